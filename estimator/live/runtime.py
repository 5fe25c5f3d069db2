"""Live estimation of mass and Izz from a pose stream and a command stream.

:class:`LiveEstimator` is the core without any network code: feed it decoded pose
and command messages (:meth:`~LiveEstimator.pose`, :meth:`~LiveEstimator.command`)
and call :meth:`~LiveEstimator.process` with the host time; it aligns them
(:class:`estimator.live.align.LiveAligner`: commands are a zero-order hold, a pose
waits up to ``max_wait_s`` for a late command, occluded / non-finite / repeated /
too-old samples are counted and skipped), runs the lean EKF
(:func:`estimator.filters.ekf.ekf_predict`, :func:`estimator.filters.ekf.ekf_update`) pose by pose,
and hands estimate messages to ``publish`` at ``publish_rate_hz`` (0: after every
update).

``ls-ekf``: once the released poses span ``ls_window_s``, batch least squares
(:func:`estimator.batch.least_squares.batch_ls`) runs on that window in a background thread while
the EKF keeps filtering live; when it returns, a second filter starts from its mean
and full covariance at the window's first pose and re-filters the buffered poses a
chunk at a time between live messages (``catch-up``); when it has caught up it
replaces the live filter. ``ls_start="reuse"`` updates with the window's poses again
(the paper), ``"handoff"`` only propagates through the window.

:func:`run_live` wires it to Zenoh (``tpods/mocap/<body>/pose``,
``tpods/<body>/cmd`` in; ``tpods/<body>/estimate`` out). :class:`LiveRecorder`
writes what the estimator saw as a run folder, flushed row by row, that
``tpods estimate batch`` can post-process.

Estimate payload (JSON), schema ``tpods.estimate/1``::

    {"schema": "tpods.estimate/1", "body": "tpods1", "seq": 12,
     "t": 1763770012.5,        # lab time of the last pose used, s
     "frame": 1500,            # its mocap frame number
     "t_pub": 1763770012.502,  # host time of publishing, s
     "method": "ls-ekf", "phase": "ls-ekf",   # ekf | ls-running | catching-up | ls-ekf | ls-failed
     "mass_kg": 2.27, "mass_sigma_kg": 0.01, "izz_kgm2": 0.00378, "izz_sigma_kgm2": 4e-6,
     "state": {"x": .., "y": .., "psi": .., "u": .., "v": .., "r": ..},
     "state_sigma": {...}, "n_updates": 1499}
"""

from __future__ import annotations

import bisect
import collections
import contextlib
import functools
import json
import math
import queue
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from common.wire import EST_FMT as _EST_FMT
from common.wire import EST_SCHEMA, decode_estimate, encode_estimate  # noqa: F401  (re-exported)
from estimator.filters.ekf import PAPER, STATE_NAMES, EkfConfig, ekf_predict, ekf_update
from estimator.live import worker as live_worker
from estimator.live.align import LiveAligner
from estimator.plant.model import wrench

LIVE_METHODS = ("ekf", "ls-ekf")
_ZERO_W = (0.0, 0.0, 0.0)
DEFAULT_MAX_WAIT_S = 0.002
"""Default bound on how long a pose waits for a late command (host seconds, counted from
the earlier of its capture and arrival times). Commands cross Zenoh in 0.1-1 ms on one
host or a LAN; a real mocap's own latency (3+ ms for VICON) means its poses are usually
released on arrival. Keeps pose-to-estimate latency within a few milliseconds."""
DEFAULT_REWIND_S = 2.0
"""How far back (lab seconds) a command arriving after the poses it governs still
corrects the live filter: it restores the state saved before the command and re-filters
the poses since (``LiveConfig.rewind_s``; 0 turns this off)."""
DIVERGED_NIS = 10.0
"""A mean normalised innovation squared above this over the last ``NIS_WINDOW``
updates (3 expected) flags the filter as diverged, as the batch EKF does."""
NIS_WINDOW = 200


@functools.cache
def _nis_limits() -> np.ndarray:
    """``max(4, chi2_0.999(3n) / n)`` for n = 0 .. NIS_WINDOW (index n)."""
    from scipy.stats import chi2

    n = np.arange(1, NIS_WINDOW + 1)
    return np.concatenate([[np.inf], np.maximum(4.0, chi2.ppf(0.999, 3 * n) / n)])


@dataclass(frozen=True)
class LiveConfig:
    """Settings of the live estimator (SI units; host seconds for waits and rates)."""

    method: str = "ekf"
    ekf: EkfConfig = PAPER
    ls_window_s: float = 20.0
    ls_start: str = "reuse"
    max_wait_s: float = DEFAULT_MAX_WAIT_S
    publish_rate_hz: float = 10.0
    catchup_budget_s: float = 0.0005
    ls_in_process: bool = False
    n_channels: int = 4
    rewind_s: float = DEFAULT_REWIND_S

    def __post_init__(self) -> None:
        from common.errors import UserError

        if self.method not in LIVE_METHODS:
            raise UserError(f"method must be one of {', '.join(LIVE_METHODS)}")
        if self.ls_start not in ("reuse", "handoff"):
            raise UserError("ls_start must be reuse or handoff")
        if not (self.max_wait_s >= 0 and math.isfinite(self.max_wait_s)):
            raise UserError("the alignment wait must be a non-negative number of seconds")
        if not (self.publish_rate_hz >= 0 and math.isfinite(self.publish_rate_hz)):
            raise UserError("the publish rate must be >= 0 Hz (0: every update)")
        if self.ls_window_s <= 0:
            raise UserError("the LS window must be positive")
        if not (self.rewind_s >= 0 and math.isfinite(self.rewind_s)):
            raise UserError("the rewind horizon must be a non-negative number of seconds")


# --------------------------------------------------------------------------------------
# Run-folder recorder


class LiveRecorder:
    """What the live estimator saw, as a run folder written as it goes.

    - ``commands.csv``: every command received (``set``, ``hold``, ``end``; also those too
      late for the live filter) in arrival order, times from ``t0`` (the first command's
      lab time); flushed per row.
    - ``poses.csv``: the aligned poses the filter used, written as soon as a command
      row at or after them exists (so the folder is always a valid run: a kill loses
      at most the poses after the last command or hold message, 0.1 s by default).
    - ``estimates.csv``: the filter's mean and sigma after every update.
    - ``run.json``: settings, ``t0_lab``, status (``running`` until the end: left
      behind, it means the process died), counters and the final estimate.
    """

    def __init__(self, out: str | Path, meta: dict[str, Any], n_channels: int = 4,
                 flush_every_s: float = 0.1) -> None:
        from common.errors import UserError

        self.out = Path(out)
        try:
            self.out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise UserError(f"{self.out}: cannot create the output folder ({exc.strerror})") from None
        if (self.out / "poses.csv").exists():
            raise UserError(f"{self.out} already holds a run (poses.csv); choose another --out")
        self.meta = dict(meta)
        self.meta.setdefault("status", "running")
        self.t0: float | None = None
        self.n_channels = n_channels
        self._cmd = (self.out / "commands.csv").open("w", buffering=1)
        self._cmd.write("t," + ",".join(f"d{i + 1}" for i in range(n_channels)) + "\n")
        self._pose = (self.out / "poses.csv").open("w", buffering=1)
        self._pose.write("t,x,y,psi\n")
        self._est = (self.out / "estimates.csv").open("w")
        self._est.write("t,frame,phase,mass_kg,mass_sigma_kg,izz_kgm2,izz_sigma_kgm2,"
                        + ",".join(STATE_NAMES[:6]) + ","
                        + ",".join(f"sigma_{n}" for n in STATE_NAMES[:6]) + "\n")
        for fh in (self._cmd, self._pose, self._est):
            fh.flush()
        self.last_cmd_t = -math.inf
        self.last_duty: tuple[float, ...] | None = None
        self.last_pose_t = -math.inf
        self._pending: list[tuple[float, float, float, float]] = []
        self.counts = {"commands": 0, "commands_unrecorded": 0, "poses": 0, "estimates": 0}
        self._flush_every = flush_every_s
        self._last_flush = time.monotonic()
        self.closed = False
        self.write_meta()

    def write_meta(self) -> None:
        self.meta["t0_lab"] = self.t0
        tmp = self.out / "run.json.tmp"
        tmp.write_text(json.dumps(self.meta, indent=2, default=_json_default) + "\n")
        tmp.replace(self.out / "run.json")

    def command(self, t: float, duty) -> None:
        if self.t0 is None:
            self.t0 = t
            self.write_meta()
        if not t > self.last_cmd_t:
            self.counts["commands_unrecorded"] += 1
            return
        self._cmd.write("%.9f," % (t - self.t0) + ",".join("%.6g" % x for x in duty) + "\n")  # noqa: UP031
        self._cmd.flush()
        self.last_cmd_t = t
        self.last_duty = tuple(duty)
        self.counts["commands"] += 1
        self._write_covered()

    def pose(self, t: float, x: float, y: float, yaw: float) -> None:
        self._pending.append((t, x, y, yaw))
        self._write_covered()

    def _write_covered(self) -> None:
        if not self._pending or self.t0 is None:
            return
        n = 0
        for p in self._pending:
            if p[0] > self.last_cmd_t:
                break
            if p[0] > self.last_pose_t and p[0] >= self.t0:
                self._pose.write("%.9f,%.12g,%.12g,%.12g\n" % (p[0] - self.t0, p[1], p[2], p[3]))  # noqa: UP031
                self.last_pose_t = p[0]
                self.counts["poses"] += 1
            n += 1
        if n:
            del self._pending[:n]
            self._pose.flush()

    def estimate(self, t: float, frame: int, phase: str, z: np.ndarray, sig: np.ndarray) -> None:
        t0 = self.t0 if self.t0 is not None else t
        self._est.write("%.9f,%d,%s," % (t - t0, frame, phase)  # noqa: UP031
                        + "%.10g,%.6g,%.10g,%.6g," % (z[6], sig[6], z[7], sig[7])  # noqa: UP031
                        + ",".join("%.10g" % v for v in z[:6]) + ","  # noqa: UP031
                        + ",".join("%.6g" % v for v in sig[:6]) + "\n")  # noqa: UP031
        self.counts["estimates"] += 1
        now = time.monotonic()
        if now - self._last_flush >= self._flush_every:
            self._est.flush()
            self._last_flush = now

    def close(self, status: str, extra: dict[str, Any] | None = None) -> None:
        """Close the files: a last hold row covers the poses still pending."""
        if self.closed:
            return
        self.closed = True
        if self._pending and self.last_duty is not None:
            t_last = self._pending[-1][0]
            if t_last > self.last_cmd_t:
                self.command(t_last, self.last_duty)
        for fh in (self._cmd, self._pose, self._est):
            with contextlib.suppress(OSError):
                fh.close()
        self.meta["status"] = status
        self.meta["recorded"] = dict(self.counts)
        self.meta.update(extra or {})
        with contextlib.suppress(OSError):
            self.write_meta()


def _json_default(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


# --------------------------------------------------------------------------------------
# The estimator core


@dataclass
class LiveCounters:
    poses_rx: int = 0
    cmds_rx: int = 0
    malformed: int = 0
    other_body: int = 0
    updates: int = 0
    estimates_published: int = 0
    publish_errors: int = 0
    catchup_updates: int = 0
    max_backlog: int = 0
    max_queue: int = 0
    rewinds: int = 0
    rewind_updates: int = 0


class LiveEstimator:
    """Align, filter and publish (no network code; see the module docstring).

    Args:
        table: thrust table used by the estimator (duty percent to newtons).
        config: :class:`LiveConfig`.
        body: the body name (estimate messages, sanity check of incoming messages).
        publish: called with each estimate message (a dict).
        recorder: optional :class:`LiveRecorder`.
    """

    def __init__(self, table, config: LiveConfig | None = None, body: str = "tpods1",
                 publish: Callable[[dict[str, Any]], None] | None = None,
                 recorder: LiveRecorder | None = None) -> None:
        self.table = table
        self.config = config or LiveConfig()
        self.body = body
        self.publish = publish
        self._body_json = json.dumps(body)
        self.recorder = recorder
        self._R = self.config.ekf.R
        self.publish_bytes: Callable[[bytes], None] | None = None
        """Alternative to ``publish``: called with the encoded payload (the fast path)."""
        self.aligner = LiveAligner(max_wait_s=self.config.max_wait_s,
                                   n_channels=self.config.n_channels)
        self.counters = LiveCounters()
        self._wrench: dict[float, tuple[float, float, float]] = {}
        self.z: np.ndarray | None = None
        self.P: np.ndarray | None = None
        self.t_last: float | None = None
        self.frame_last = -1
        self.last_nis = math.nan
        self.phase = "ekf"
        self.hist_t: list[float] = []
        self.hist_pose: list[tuple[float, float, float]] = []
        self.ls_result = None
        self.ls_error: str | None = None
        self.ls_elapsed_s: float | None = None
        self._ls_future = None
        self._pool = None
        if self.config.method == "ls-ekf":
            self._executor()
        self._cu: dict[str, Any] | None = None
        self.restart_t: float | None = None
        self.end_seen_t: float | None = None
        self._last_pub = -math.inf
        self._seq = 0
        self.history: list[tuple[float, float, float, float, float]] = []
        """(t, mass, mass sigma, izz, izz sigma) after every update (for plots)."""
        self._ck: list[tuple[float, int, np.ndarray, np.ndarray]] = []
        """Checkpoints of the live filter within ``rewind_s``: (pose t, index in hist, z, P)."""
        self._rewind_t: float | None = None
        self._nis_recent: collections.deque[float] = collections.deque(maxlen=NIS_WINDOW)
        _nis_limits()  # scipy.stats now, not in the middle of a stream

    # ------------------------------------------------------------------ input
    def command(self, d: dict[str, Any]) -> bool:
        """A decoded ``tpods.cmd/1`` message. Returns whether it was accepted."""
        self.counters.cmds_rx += 1
        if d.get("body") not in (None, self.body):
            self.counters.other_body += 1
            return False
        t, duty = d["t"], d["duty"]
        late_before = self.aligner.stats.cmds_late
        self.aligner.rewind_floor = self._ck[0][0] if self._ck else math.inf
        if not self.aligner.push_command(t, duty):
            if self.aligner.stats.cmds_late > late_before:
                # too late for the live filter (it cannot rewrite the past), but the run
                # folder keeps it for post-processing
                if self.recorder is not None:
                    self.recorder.command(t, duty)
                if d.get("kind") == "end":
                    self.end_seen_t = t
            return False
        try:
            thrust = self.table.thrust_n(np.asarray([duty], float), clamp=True)[0]
        except Exception:  # a duty the table cannot map (outside 0..100 never gets here)
            thrust = np.zeros(self.config.n_channels)
        w = wrench(thrust, self.config.ekf.arm_m)
        self._wrench[float(t)] = (float(w[0]), float(w[1]), float(w[2]))
        if d.get("kind") == "end":
            self.end_seen_t = t
        if self.recorder is not None:
            self.recorder.command(t, duty)
        if self.t_last is not None and t <= self.t_last:
            # the filter already went past it: re-filter from before it (in process())
            self._rewind_t = t if self._rewind_t is None else min(self._rewind_t, t)
        cu = self._cu
        if cu is not None and cu["t"] is not None and t <= cu["t"]:  # the catch-up too
            cu["rewind"] = t if cu["rewind"] is None else min(cu["rewind"], t)
        return True

    def pose(self, d: dict[str, Any], arrival: float) -> bool:
        """A decoded ``tpods.pose/1`` message received at host time ``arrival``."""
        self.counters.poses_rx += 1
        if d.get("body") not in (None, self.body):
            self.counters.other_body += 1
            return False
        t = d["t"]
        return self.aligner.push_pose(d["frame"], t, d["x"] if d["x"] is not None else math.nan,
                                      d["y"] if d["y"] is not None else math.nan,
                                      d["yaw"] if d["yaw"] is not None else math.nan,
                                      occluded=bool(d["occluded"]), arrival=min(t, arrival))

    def next_deadline(self) -> float | None:
        """Host time by which :meth:`process` must run again (a pose's wait ends)."""
        return self.aligner.next_deadline()

    # ------------------------------------------------------------- filtering
    def _segments(self, t0: float, t1: float):
        """Hold segments (durations s, body wrenches) from ``t0`` to ``t1``."""
        ct, _ = self.aligner.commands_between(t0, t1)
        ts = ct.tolist()
        w = self._wrench
        cmd_all = self.aligner._cmd_t
        seg_w = []
        for tc in ts:
            wi = w.get(tc)
            if wi is None:  # the command in force at t0, restamped to t0
                j = bisect.bisect_right(cmd_all, tc) - 1
                wi = w[cmd_all[j]] if j >= 0 else _ZERO_W
            seg_w.append(wi)
        if not ts or ts[0] > t0:  # nothing commanded yet at t0
            ts.insert(0, t0)
            seg_w.insert(0, _ZERO_W)
        ts.append(t1)
        seg_dt = [ts[i + 1] - ts[i] for i in range(len(ts) - 1)]
        return seg_dt, seg_w

    def _step(self, z, P, t_prev: float | None, t: float, meas, use: bool = True):
        cfg = self.config.ekf
        if t_prev is not None and t > t_prev:
            seg_dt, seg_w = self._segments(t_prev, t)
            z, P, _ = ekf_predict(z, P, seg_dt, seg_w, cfg)
        nis = math.nan
        if use:
            z, P, (nis, _) = ekf_update(z, P, meas, cfg, self._R)
        return z, P, nis

    def _start_filter(self, meas) -> None:
        z = np.array(self.config.ekf.x0, dtype=float)
        z[:3] = meas
        self.z, self.P = z, self.config.ekf.P0.copy()

    def process(self, now: float) -> int:
        """Release the aligned poses, filter them, advance a catch-up, publish. Returns updates."""
        if self._rewind_t is not None:
            self._rewind()
        ready = self.aligner.pop_ready(now)
        self.counters.max_backlog = max(self.counters.max_backlog, self.aligner.pending)
        n = 0
        for p in ready:
            meas = (p.x, p.y, p.yaw)
            if self.z is None:
                self._start_filter(meas)
                self.z, self.P, self.last_nis = self._step(self.z, self.P, None, p.t, meas)
            else:
                self.z, self.P, self.last_nis = self._step(self.z, self.P, self.t_last, p.t, meas)
            self.t_last = p.t
            self.frame_last = p.frame
            self.hist_t.append(p.t)
            self.hist_pose.append(meas)
            self.counters.updates += 1
            n += 1
            self._after_update(p.t, len(self.hist_t) - 1)
            if self.recorder is not None:
                self.recorder.pose(p.t, p.x, p.y, p.yaw)
                self.recorder.estimate(p.t, p.frame, self.phase, self.z,
                                       np.sqrt(np.maximum(self.P.diagonal(), 0.0)))
            if self.config.publish_rate_hz == 0:
                self._publish(now)
        if self.config.method == "ls-ekf":
            self._ls_tick()
        if n and self.config.publish_rate_hz > 0 and now - self._last_pub >= 1.0 / self.config.publish_rate_hz:
            self._publish(now)
        return n

    def _after_update(self, t: float, idx: int) -> None:
        """Bookkeeping after the live filter's update with pose ``hist_t[idx]``: history,
        NIS, checkpoint."""
        z, P = self.z, self.P
        self.history.append((t, float(z[6]), math.sqrt(max(P[6, 6], 0.0)),
                             float(z[7]), math.sqrt(max(P[7, 7], 0.0))))
        if not math.isnan(self.last_nis):
            self._nis_recent.append(self.last_nis)
        horizon = self.config.rewind_s
        if horizon > 0:
            ck = self._ck
            ck.append((t, idx, z.copy(), P.copy()))
            if len(ck) > 256 and ck[255][0] < t - horizon:  # drop the old ones in blocks
                cut = bisect.bisect_left([c[0] for c in ck], t - horizon)
                del ck[:cut]

    def _rewind(self) -> None:
        """A command arrived after poses it governs: restore the checkpoint at or before
        it and re-filter the poses since with the commands now known."""
        t_c, self._rewind_t = self._rewind_t, None
        ck = self._ck
        j = bisect.bisect_right([c[0] for c in ck], t_c) - 1
        if j < 0:  # older than every checkpoint (the aligner refuses those): nothing to do
            return
        t_prev, idx, z, P = ck[j]
        del ck[j + 1:]
        del self.history[len(self.history) - (len(self.hist_t) - 1 - idx):]
        self.z, self.P, self.t_last = z.copy(), P.copy(), t_prev
        n = 0
        for i in range(idx + 1, len(self.hist_t)):
            t = self.hist_t[i]
            self.z, self.P, self.last_nis = self._step(self.z, self.P, self.t_last, t,
                                                       self.hist_pose[i])
            self.t_last = t
            self._after_update(t, i)
            n += 1
        self.counters.rewinds += 1
        self.counters.rewind_updates += n

    @property
    def diverged(self) -> bool:
        """Non-physical or non-finite mass or Izz, a covariance that broke down, or a mean
        NIS over the last updates above :data:`DIVERGED_NIS` (the batch EKF's test)."""
        if self.z is None:
            return False
        z, P = self.z, self.P
        if not (z[6] > 0 and z[7] > 0 and np.all(np.isfinite(z))):
            return True
        if not (P[6, 6] > 0 and P[7, 7] > 0 and np.all(np.isfinite(P))):
            return True
        return self._nis_recent_mean() > DIVERGED_NIS

    def _nis_recent_mean(self) -> float:
        nis = self._nis_recent
        return sum(nis) / len(nis) if len(nis) >= min(NIS_WINDOW, 20) else math.nan

    @property
    def inconsistent(self) -> bool:
        """The recent innovations are larger than the covariance allows (mean NIS over the
        last updates above ``max(4, chi2_0.999(3n) / n)``, the batch EKF's test): the
        reported sigma is not to be trusted, though the filter has not diverged."""
        mean = self._nis_recent_mean()
        if not math.isfinite(mean):
            return False
        return bool(mean > _nis_limits()[len(self._nis_recent)])

    # ------------------------------------------------------------------ ls-ekf
    def _ls_tick(self, block: bool = False) -> None:
        if self.phase == "ekf" and self._ls_future is None and self.hist_t \
                and self.hist_t[-1] - self.hist_t[0] >= self.config.ls_window_s:
            self._start_ls()
        if self._ls_future is not None and self.phase == "ls-running":
            if block or self._ls_future.done():
                self._ls_done()
        if self._cu is not None:
            self._catch_up(block)

    def _executor(self):
        """One background worker for the batch fit: a separate spawned process when
        ``config.ls_in_process`` (the live loop keeps its interpreter to itself; the
        command line does this; a script doing it needs the usual
        ``if __name__ == "__main__":`` guard), else a thread."""
        if self._pool is None:
            import concurrent.futures as cf
            import multiprocessing as mp

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
        cmd_t, duty = self.aligner.commands()
        thrust = self.table.thrust_n(duty, clamp=True)
        cfg = self.config.ekf
        kw = {"sigma_pos_m": cfg.sigma_meas[0], "sigma_yaw_rad": cfg.sigma_meas[2],
              "fixed": {"arm": cfg.arm_m, "ct": cfg.ct, "cr": cfg.cr, "kb": cfg.kb,
                        "ax": cfg.ax, "ay": cfg.ay}}
        self._ls_n = n
        self.phase = "ls-running"
        try:
            self._ls_future = self._executor().submit(live_worker.ls_job, pose_t, pose, cmd_t - t0, thrust, kw)
        except Exception:  # a broken process pool: fall back to a thread
            import concurrent.futures as cf

            self._pool = cf.ThreadPoolExecutor(1, thread_name_prefix="live-ls")
            self._ls_future = self._pool.submit(live_worker.ls_job, pose_t, pose, cmd_t - t0, thrust, kw)

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
        z0, P0 = np.array(res.z0, float), 0.5 * (res.cov + res.cov.T)
        self._cu = {"z": z0, "P": P0, "z0": z0, "P0": P0, "i": 0, "t": None, "n_win": self._ls_n,
                    "ck": [], "rewind": None}
        self.phase = "catching-up"

    def close_pool(self) -> None:
        """Stop the background worker (idempotent)."""
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None

    def _catch_up(self, block: bool) -> None:
        """Re-filter buffered poses from the LS start for at most ``catchup_budget_s``.

        Keeps checkpoints over the last ``rewind_s`` like the live filter, so a late
        command rewinds the catch-up too, and the live filter can rewind after takeover.
        """
        cu = self._cu
        reuse = self.config.ls_start == "reuse"
        ck = cu["ck"]
        if cu["rewind"] is not None:  # a command arrived for a time it already passed
            t_c, cu["rewind"] = cu["rewind"], None
            j = bisect.bisect_right([c[0] for c in ck], t_c) - 1
            if j >= 0:
                t_k, idx, zk, Pk = ck[j]
                del ck[j + 1:]
                cu.update(z=zk.copy(), P=Pk.copy(), t=t_k, i=idx + 1)
            else:  # no checkpoint that old: from the LS start again
                ck.clear()
                cu.update(z=cu["z0"], P=cu["P0"], t=None, i=0)
        z, P, t_prev = cu["z"], cu["P"], cu["t"]
        i = cu["i"]
        n_win = cu["n_win"]
        hist_t, hist_pose = self.hist_t, self.hist_pose
        horizon = self.config.rewind_s
        deadline = time.perf_counter() + self.config.catchup_budget_s
        while i < len(hist_t):
            t = hist_t[i]
            z, P, _ = self._step(z, P, t_prev, t, hist_pose[i], reuse or i >= n_win)
            if horizon > 0 and t >= hist_t[-1] - horizon:
                ck.append((t, i, z.copy(), P.copy()))
            t_prev = t
            i += 1
            self.counters.catchup_updates += 1
            if not block and time.perf_counter() > deadline:
                break
        if len(ck) > 256 and ck[255][0] < hist_t[-1] - horizon:
            del ck[:bisect.bisect_left([c[0] for c in ck], hist_t[-1] - horizon)]
        cu.update(z=z, P=P, t=t_prev, i=i)
        if i >= len(hist_t):  # caught up with the live filter: take over
            self.z, self.P, self.t_last = z, P, t_prev
            self._cu = None
            self._ck = ck  # the new filter's checkpoints replace the old filter's
            self._rewind_t = None
            self.phase = "ls-ekf"
            self.restart_t = t_prev

    # ---------------------------------------------------------------- output
    def estimate(self, now: float | None = None) -> dict[str, Any] | None:
        """The current estimate message (None before the first update)."""
        if self.z is None:
            return None
        z = self.z
        sig = np.sqrt(np.maximum(self.P.diagonal(), 0.0))
        return {
            "schema": EST_SCHEMA, "body": self.body, "seq": self._seq,
            "t": self.t_last, "frame": self.frame_last,
            "t_pub": time.time() if now is None else now,
            "method": self.config.method, "phase": self.phase,
            "mass_kg": float(z[6]), "mass_sigma_kg": float(sig[6]),
            "izz_kgm2": float(z[7]), "izz_sigma_kgm2": float(sig[7]),
            "state": dict(zip(STATE_NAMES[:6], z[:6].tolist(), strict=True)),
            "state_sigma": dict(zip(STATE_NAMES[:6], sig[:6].tolist(), strict=True)),
            "n_updates": self.counters.updates,
            "nis": None if math.isnan(self.last_nis) else float(self.last_nis),
            "diverged": self.diverged,
            "inconsistent": self.inconsistent,
        }

    def _publish(self, now: float) -> None:
        self._last_pub = now
        if self.z is None or (self.publish is None and self.publish_bytes is None):
            return
        self._seq += 1
        try:
            if self.publish_bytes is not None:
                self.publish_bytes(self._encode())
            else:
                msg = self.estimate()
                msg["seq"] = self._seq
                self.publish(msg)
            self.counters.estimates_published += 1
        except Exception:
            self.counters.publish_errors += 1

    def _encode(self) -> bytes:
        """The current estimate as a ``tpods.estimate/1`` payload (same keys as :meth:`estimate`)."""
        z = self.z.tolist()
        d = self.P.diagonal().tolist()
        sg = [math.sqrt(v) if v > 0 else 0.0 for v in d]
        nis = "null" if math.isnan(self.last_nis) else repr(float(self.last_nis))
        return (_EST_FMT % (self._body_json, self._seq, self.t_last, self.frame_last, time.time(),
                            self.config.method, self.phase, z[6], sg[6], z[7], sg[7],
                            *z[:6], *sg[:6], self.counters.updates, nis,
                            "true" if self.diverged else "false",
                            "true" if self.inconsistent else "false")).encode()

    def finish(self) -> dict[str, Any] | None:
        """End of stream: release every pending pose, finish an ls-ekf restart, publish."""
        self.process(math.inf)
        if self.config.method == "ls-ekf":
            if self.phase == "ekf" and self.hist_t and \
                    self.hist_t[-1] - self.hist_t[0] >= self.config.ls_window_s:
                self._start_ls()
            self._ls_tick(block=True)
            self.close_pool()
        self._publish(time.time())
        return self.estimate()

    def stats(self) -> dict[str, Any]:
        d = asdict(self.counters)
        d.update({f"align_{k}": v for k, v in self.aligner.stats.as_dict().items()})
        d["pending"] = self.aligner.pending
        return d

    def summary(self) -> dict[str, Any]:
        """Final estimate, phase, LS details and counters (JSON-ready)."""
        est = self.estimate() or {}
        out = {k: est.get(k) for k in ("method", "phase", "mass_kg", "mass_sigma_kg", "izz_kgm2",
                                       "izz_sigma_kgm2", "state", "state_sigma", "n_updates",
                                       "diverged", "inconsistent")}
        out["t_last_lab"] = self.t_last
        out["restart_t_lab"] = self.restart_t
        if self.ls_result is not None:
            r = self.ls_result
            out["ls"] = {"mass_kg": r.mass_kg, "mass_sigma_kg": r.mass_sigma_kg,
                         "izz_kgm2": r.izz_kgm2, "izz_sigma_kgm2": r.izz_sigma_kgm2,
                         "window_s": self.config.ls_window_s, "elapsed_s": self.ls_elapsed_s}
        if self.ls_error:
            out["ls_error"] = self.ls_error
        out["counters"] = self.stats()
        return out


# --------------------------------------------------------------------------------------
# Zenoh wiring


def keys(body: str, mocap_prefix: str = "tpods/mocap", prefix: str = "tpods") -> dict[str, str]:
    """The pose, command and estimate keys of a body."""
    from common.wire import cmd_key, estimate_key, pose_key

    return {"pose": pose_key(mocap_prefix, body), "cmd": cmd_key(body, prefix),
            "estimate": estimate_key(body, prefix)}


@dataclass
class LiveRun:
    """Outcome of :func:`run_live`."""

    status: str
    summary: dict[str, Any]
    elapsed_s: float
    rates: dict[str, float] = field(default_factory=dict)


def run_live(session, estimator: LiveEstimator, *, stop: threading.Event | None = None,
             duration_s: float | None = None, exit_on_end: bool = False,
             end_grace_s: float = 0.5, mocap_prefix: str = "tpods/mocap", prefix: str = "tpods",
             on_console: Callable[[str], None] | None = None, console_period_s: float = 1.0
             ) -> LiveRun:
    """Subscribe, estimate and publish until ``stop``, ``duration_s`` or (with
    ``exit_on_end``) ``end_grace_s`` after the player's ``end`` command.

    Zenoh callbacks only queue the payloads with their arrival time; this thread
    decodes, aligns, filters and publishes, sleeping until the next message or the
    next pose's wait deadline.
    """
    import zenoh

    from common.wire import ENCODING, decode_command, decode_pose

    stop = stop or threading.Event()
    k = keys(estimator.body, mocap_prefix, prefix)
    q: queue.SimpleQueue = queue.SimpleQueue()
    now = time.time
    bad: dict[str, int] = {}

    def on_pose(sample) -> None:
        q.put((0, sample.payload.to_bytes(), now()))

    def on_cmd(sample) -> None:
        q.put((1, sample.payload.to_bytes(), now()))

    pub = session.declare_publisher(k["estimate"], encoding=zenoh.Encoding(ENCODING),
                                    express=True)

    estimator.publish_bytes = pub.put
    subs = [session.declare_subscriber(k["pose"], on_pose),
            session.declare_subscriber(k["cmd"], on_cmd)]
    t_start = time.monotonic()
    t_end = None if duration_s is None else t_start + duration_s
    next_console = t_start + console_period_s
    last_counts = (0, 0)
    rates = {"poses_hz": 0.0, "cmds_hz": 0.0}
    end_host: float | None = None
    status = "success"
    try:
        while not stop.is_set():
            mono = time.monotonic()
            if t_end is not None and mono >= t_end:
                break
            if end_host is None and exit_on_end and estimator.end_seen_t is not None:
                end_host = mono
            if end_host is not None and mono - end_host >= end_grace_s and q.empty():
                break
            dl = estimator.next_deadline()
            timeout = 0.05 if dl is None else min(0.05, max(0.0, dl - now()))
            try:
                item = q.get(timeout=timeout) if timeout > 0 else q.get_nowait()
            except queue.Empty:
                item = None
            batch = 0
            if item is not None:
                qs = q.qsize() + 1
                if qs > estimator.counters.max_queue:
                    estimator.counters.max_queue = qs
            while item is not None:
                kind, payload, arr = item
                if kind == 0:
                    d = decode_pose(payload, bad)
                    if d is None:
                        estimator.counters.malformed += 1
                    else:
                        estimator.pose(d, arr)
                else:
                    c = decode_command(payload, bad, estimator.config.n_channels)
                    if c is None:
                        estimator.counters.malformed += 1
                    else:
                        estimator.command(c)
                batch += 1
                if batch >= 64:
                    break
                try:
                    item = q.get_nowait()
                except queue.Empty:
                    item = None
            estimator.process(now())
            if time.monotonic() >= next_console:
                c = estimator.counters
                el = time.monotonic() - next_console + console_period_s
                rates = {"poses_hz": (c.poses_rx - last_counts[0]) / el,
                         "cmds_hz": (c.cmds_rx - last_counts[1]) / el}
                last_counts = (c.poses_rx, c.cmds_rx)
                next_console = time.monotonic() + console_period_s
                if on_console is not None:
                    on_console(console_line(estimator, rates, q.qsize()))
    except (KeyboardInterrupt, Exception):
        status = "aborted"
        raise
    finally:
        for s in subs:
            with contextlib.suppress(Exception):
                s.undeclare()
        # what is still queued was received: use it
        while True:
            try:
                kind, payload, arr = q.get_nowait()
            except queue.Empty:
                break
            with contextlib.suppress(Exception):
                d = decode_pose(payload, bad) if kind == 0 else decode_command(payload, bad)
                if d is not None:
                    (estimator.pose(d, arr) if kind == 0 else estimator.command(d))
        if status == "success":
            estimator.finish()
        else:
            with contextlib.suppress(Exception):
                estimator.process(math.inf)
        estimator.close_pool()
        with contextlib.suppress(Exception):
            pub.undeclare()
        estimator.publish_bytes = None
    if status == "success" and stop.is_set():
        status = "stopped"
    return LiveRun(status, estimator.summary(), time.monotonic() - t_start, rates)


def console_line(est: LiveEstimator, rates: dict[str, float], backlog: int = 0) -> str:
    """One line of live status: estimates with sigma, input rates, counters."""
    e = est.estimate()
    a = est.aligner.stats
    c = est.counters
    if e is None:
        head = "waiting for poses and commands"
    else:
        t_rel = (est.t_last - est.aligner.first_command_t) if est.aligner.first_command_t else 0.0
        head = (f"t {t_rel:7.2f} s | m {e['mass_kg']:.4f} +/- {e['mass_sigma_kg']:.2g} kg | "
                f"Izz {e['izz_kgm2']:.4e} +/- {e['izz_sigma_kgm2']:.1e} | {est.phase}"
                + (" | DIVERGED" if e["diverged"] else " | INCONSISTENT" if e["inconsistent"] else ""))
    return (f"live: {head} | in {rates.get('poses_hz', 0):.0f} poses/s "
            f"{rates.get('cmds_hz', 0):.0f} cmds/s | used {c.updates} occl {a.occluded} "
            f"dup {a.duplicates} old {a.too_old} late-cmd {a.cmds_late} rewound {a.cmds_rewound} "
            f"timeout {a.released_by_timeout} bad {c.malformed} | backlog {backlog + est.aligner.pending}")
