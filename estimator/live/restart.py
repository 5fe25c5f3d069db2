"""The ``ls-ekf`` restart of the live estimator: batch LS on the first window, then catch-up.

Once the released poses span ``ls_window_s``, batch least squares
(:func:`estimator.batch.least_squares.batch_ls`, through :mod:`estimator.live.worker`) runs
on that window in a background worker (a low-priority process, or a thread) while the EKF
keeps filtering live (phase ``ls-running``); when it returns, a second filter starts from
its mean and full covariance at the window's first pose and re-filters the buffered poses
a slice of ``catchup_budget_s`` at a time between live messages (``catching-up``); when it
has caught up it replaces the live filter (``ls-ekf``). ``ls_start="reuse"`` updates with
the window's poses again (the paper), ``"handoff"`` only propagates through the window.
If the fit fails the EKF carries on (``ls-failed``).

:class:`LsEkfRestart` is a part of :class:`estimator.live.core.LiveEstimator` (a mixin):
it reads the estimator's pose history, aligner, thrusts (:mod:`estimator.live.thrust_part`)
and ``_step``, keeps its checkpoints as the live filter does (:mod:`estimator.live.history`),
and on takeover sets the estimator's filter state.
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing as mp
import sys
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from estimator.live import worker as live_worker
from estimator.live.history import checkpoint_at, history_entry, prune_checkpoints
from estimator.live.scan_job import scan_ls_job

IDLE_SLICE_S = 0.005
"""Longest stretch of catch-up in the live loop's idle time (host s): the loop's other
duties (deadlines, console) wait at most this long."""


class LsEkfRestart:
    """The ``ls-ekf`` start and catch-up of :class:`~estimator.live.core.LiveEstimator`."""

    def _init_ls(self) -> None:
        self.ls_result = None
        self.ls_error: str | None = None
        self.ls_elapsed_s: float | None = None
        self._ls_future = None
        self._pool = None
        if self.config.method == "ls-ekf":
            self._executor()
        self._cu: dict[str, Any] | None = None

    def _ls_tick(self, block: bool = False) -> None:
        if self.phase == "ekf" and self._ls_future is None and self.hist_t \
                and self.hist_t[-1] - self.hist_t[0] >= self.config.ls_window_s \
                and self._window_commands_known():
            self._start_ls()
        if self._ls_future is not None and self.phase == "ls-running":
            if block or self._ls_future.done():
                self._ls_done()
        if self._cu is not None:
            self._catch_up(block)

    def _window_commands_known(self) -> bool:
        """A structure's window fit waits until every module's commands over the window
        are known (the merger has emitted a row at or after its end; at most a heartbeat,
        0.1 s): a module whose stream lags would otherwise be fitted with its last value
        held. (A module's own fit starts at once, as it always has.)"""
        if self.structure is None:
            return True
        t_end = self.hist_t[0] + self.config.ls_window_s
        cmd_t = self.aligner._cmd_t
        return bool(cmd_t) and cmd_t[-1] >= min(t_end, self.hist_t[-1])

    def _executor(self):
        """One background worker for the batch fit: a separate spawned process when
        ``config.ls_in_process`` (the live loop keeps its interpreter to itself; the
        command line does this; a script doing it needs the usual
        ``if __name__ == "__main__":`` guard), else a thread."""
        if self._pool is None:
            if self.config.ls_in_process:
                try:
                    self._pool = cf.ProcessPoolExecutor(1, mp_context=mp.get_context("spawn"),
                                                        initializer=live_worker.init)
                    self._pool.submit(live_worker.warm)  # import numpy/scipy now, not at the window's end
                except Exception:  # no process pool here: a thread does it
                    self._pool = None
            if self._pool is None:
                self._pool = cf.ThreadPoolExecutor(1, thread_name_prefix="live-ls")
        return self._pool

    def _start_ls(self) -> None:
        t0 = self.hist_t[0]
        n = int(np.searchsorted(np.asarray(self.hist_t), t0 + self.config.ls_window_s, "right"))
        pose_t = np.asarray(self.hist_t[:n]) - t0
        pose = np.asarray(self.hist_pose[:n])
        cmd_t, thrust, sens = self._input_rows(*self.aligner.commands())
        kw = self._ls_kwargs()
        self._ls_n = n
        self.phase = "ls-running"
        job, extra = live_worker.ls_job, ()
        if getattr(self, "_scan_reach_m", None) is not None:  # a vehicle of unknown mass
            job, extra = scan_ls_job, (self._scan_reach_m,)
        try:
            self._ls_future = self._executor().submit(job, pose_t, pose, cmd_t - t0, thrust, kw,
                                                      sens, *extra)
        except Exception:  # a broken process pool: fall back to a thread
            self._pool = cf.ThreadPoolExecutor(1, thread_name_prefix="live-ls")
            self._ls_future = self._pool.submit(job, pose_t, pose, cmd_t - t0, thrust, kw, sens,
                                                *extra)

    def _ls_kwargs(self, initial=None) -> dict[str, Any]:
        """Keyword arguments of the batch LS fits of the live estimator (window, end of
        run): the filter's noise and known terms; for a structure its unknowns and start
        (:meth:`common.structure.Structure.initial_guess`, as ``tpods estimate batch``)."""
        cfg = self.config.ekf
        kw: dict[str, Any] = {"sigma_pos_m": cfg.sigma_meas[0], "sigma_yaw_rad": cfg.sigma_meas[2],
                              "fixed": cfg.known_params}
        if self.structure is not None:
            kw["names"] = self._names
            kw["fixed"].update({k: v for k, v in self._fixed.items() if k in ("cx", "cy")})
            kw["initial"] = dict(self._guess)
            if (prior := self._prior_vector()) is not None:
                kw["prior"] = prior
        if initial:
            kw["initial"] = {**kw.get("initial", {}), **initial}
        return kw

    def _ls_done(self) -> None:
        try:
            res, self.ls_elapsed_s = self._ls_future.result()
            if not res.converged:
                self.ls_error = f"did not converge ({res.message})"
            elif res.z0[6] <= 0 or res.z0[7] <= 0 or not np.all(np.isfinite(res.cov)):
                self.ls_error = "non-physical start (mass or Izz <= 0)"
            else:
                self.ls_result = res
        except Exception as exc:  # reported, the EKF carries on
            self.ls_error = f"{exc.__class__.__name__}: {exc}"
        self.close_pool()
        if self.ls_result is None:
            self.phase = "ls-failed"
            print(f"live: batch LS on the first window failed ({self.ls_error}); "
                  "continuing with the EKF alone", file=sys.stderr)
            return
        res = self.ls_result
        if res.cov_thrust is not None:  # the window's thrust part, relative, carried forward
            self._set_thrust_rel(res, "the LS window")
            cov = res.cov_noise  # the filter carries the noise part; the thrust part is added
        else:
            cov = res.cov
        z0, P0 = np.array(res.z0, float), 0.5 * (cov + cov.T)
        self._cu = {"z": z0, "P": P0, "z0": z0, "P0": P0, "i": 0, "t": None, "n_win": self._ls_n,
                    "ck": [], "rewind": None}
        self.phase = "catching-up"

    def close_pool(self) -> None:
        """Stop the background worker (idempotent)."""
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None

    def idle_catch_up(self, waiting: Callable[[], bool]) -> bool:
        """Go on with the catch-up in the live loop's idle time: pose after pose until
        ``waiting()`` says a message arrived (checked after each, the interpreter lock
        released in between so that a receiving thread can queue it) or
        :data:`IDLE_SLICE_S` passed. Returns whether there was a catch-up to go on with."""
        if self._cu is None:
            return False
        self._catch_up(False, waiting)
        return True

    def _catch_up(self, block: bool, waiting: Callable[[], bool] | None = None) -> None:
        """Re-filter buffered poses from the LS start for at most ``catchup_budget_s`` (with
        ``waiting``: :meth:`idle_catch_up`).

        Keeps checkpoints over the last ``rewind_s`` like the live filter, so a late
        command rewinds the catch-up too, and the live filter can rewind after takeover.
        """
        cu = self._cu
        reuse = self.config.ls_start == "reuse"
        ck = cu["ck"]
        if cu["rewind"] is not None:  # a command arrived for a time it already passed
            t_c, cu["rewind"] = cu["rewind"], None
            c = checkpoint_at(ck, t_c)
            if c is not None:
                t_k, idx, zk, Pk = c
                cu.update(z=zk.copy(), P=Pk.copy(), t=t_k, i=idx + 1)
            else:  # no checkpoint that old: from the LS start again
                ck.clear()
                cu.update(z=cu["z0"], P=cu["P0"], t=None, i=0)
        z, P, t_prev = cu["z"], cu["P"], cu["t"]
        i = cu["i"]
        n_win = cu["n_win"]
        hist_t, hist_pose = self.hist_t, self.hist_pose
        horizon = self.config.rewind_s
        deadline = time.perf_counter() + (self.config.catchup_budget_s if waiting is None
                                          else IDLE_SLICE_S)
        while i < len(hist_t):
            t = hist_t[i]
            z, P, _ = self._step(z, P, t_prev, t, hist_pose[i], reuse or i >= n_win, k=i)
            if horizon > 0 and t >= hist_t[-1] - horizon:
                ck.append((t, i, z.copy(), P.copy()))
            t_prev = t
            i += 1
            self.counters.catchup_updates += 1
            if not block:
                if time.perf_counter() > deadline:
                    break
                if waiting is not None:
                    time.sleep(0)  # the lock to a receiving thread that waits for it
                    if waiting():
                        break
        prune_checkpoints(ck, hist_t[-1] - horizon)
        cu.update(z=z, P=P, t=t_prev, i=i)
        if i >= len(hist_t):  # caught up with the live filter: take over
            self.z, self.P, self.t_last = z, P, t_prev
            self._cu = None
            self._ck = ck  # the new filter's checkpoints replace the old filter's
            self._rewind_t = None
            self.phase = "ls-ekf"
            self.restart_t = t_prev
            if self.history and self.history[-1][0] == t_prev:
                # the history's last entry (same pose) is the new filter's from now on: a
                # takeover at the end of a run (the fit came late) still ends the history
                # at the estimate reported
                self.history[-1] = history_entry(t_prev, z, P)

