"""The live estimator core: align, filter and publish, without any network code.

:class:`LiveEstimator`: feed it decoded pose and command messages
(:meth:`~LiveEstimator.pose`, :meth:`~LiveEstimator.command`) and call
:meth:`~LiveEstimator.process` with the host time; it aligns them
(:class:`estimator.live.align.LiveAligner`: commands are a zero-order hold, a pose
waits up to ``max_wait_s`` for a late command, occluded / non-finite / repeated /
too-old samples are counted and skipped), runs the lean EKF
(:func:`estimator.filters.ekf.ekf_predict`, :func:`estimator.filters.ekf.ekf_update`) pose by pose,
re-filters from a checkpoint when a command arrives after poses it governs (``rewind_s``),
and hands estimate messages to ``publish`` at ``publish_rate_hz`` (0: after every
update). The ``ls-ekf`` start and catch-up live in :mod:`estimator.live.restart`.
"""

from __future__ import annotations

import bisect
import collections
import functools
import json
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.stats import chi2

from common.errors import UserError
from common.wire import EST_FMT as _EST_FMT
from common.wire import EST_SCHEMA, encode_estimate
from estimator.filters.ekf import (
    PAPER,
    STATE_NAMES,
    EkfConfig,
    _offset_spec,
    _predict,
    _update_offset,
    ekf_predict,
    ekf_update,
    filter_plant,
)
from estimator.live.align import LiveAligner
from estimator.live.merge import ModuleMerger
from estimator.live.restart import LsEkfRestart
from estimator.plant.model import wrench

if TYPE_CHECKING:
    from common.structure import Structure
    from estimator.live.recorder import LiveRecorder

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
STRUCTURE_NAMES = ("mass", "izz", "cx", "cy")
"""The live estimator's unknowns on a structure (issue 18): mass, Izz about the centre of
mass and the centre of mass in the tracked frame (cx or cy given as known in the
structure's [body] are fixed instead)."""


@functools.cache
def _nis_limits() -> np.ndarray:
    """``max(4, chi2_0.999(3n) / n)`` for n = 0 .. NIS_WINDOW (index n)."""
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
    before_ls: int = 0


class LiveEstimator(LsEkfRestart):
    """Align, filter and publish (no network code; see the module docstring).

    Args:
        table: thrust table used by the estimator (duty percent to newtons).
        config: :class:`LiveConfig`.
        body: the body name (estimate messages, sanity check of incoming messages).
        publish: called with each estimate message (a dict).
        recorder: optional :class:`LiveRecorder`.
        structure: a :class:`common.structure.Structure` (issue 18): the commands come
            from its modules (each message's ``body`` a module name, four duties), merged
            into the structure's 4N duties (:class:`estimator.live.merge.ModuleMerger`);
            the thrusts are its virtual thrusts; the unknowns are mass, Izz about the
            centre of mass and the centre of mass (cx, cy) in the tracked frame, with the
            extended filter's offset-aware pose update in the direct parameter form (as
            ``tpods estimate batch --method ls-ekf`` on a structure run). Only ``ls-ekf``:
            no estimate is made before the LS window's fit (from the structure's
            geometric start the EKF alone diverges; docs/estimators.md). ``table`` is then
            unused (give the structure its tables).
    """

    def __init__(self, table, config: LiveConfig | None = None, body: str = "tpods1",
                 publish: Callable[[dict[str, Any]], None] | None = None,
                 recorder: LiveRecorder | None = None,
                 structure: Structure | None = None) -> None:
        self.table = table
        self.config = config or LiveConfig()
        self.body = body
        self.structure = structure
        self.merger: ModuleMerger | None = None
        self._arrived = -math.inf
        """Latest host arrival time of a message taken in (the merger's stale clock)."""
        n_aligned = self.config.n_channels
        if structure is not None:
            if self.config.method != "ls-ekf":
                raise UserError("a structure is estimated live with --method ls-ekf only: from "
                                "its geometric start the EKF alone diverges (docs/estimators.md)")
            self.merger = ModuleMerger(tuple(m.name for m in structure.modules),
                                       width=self.config.n_channels)
            n_aligned = structure.n_channels
            self._init_structure_filter()
        self.publish = publish
        self._body_json = json.dumps(body)
        self.recorder = recorder
        self._R = self.config.ekf.R
        self.publish_bytes: Callable[[bytes], None] | None = None
        """Alternative to ``publish``: called with the encoded payload (the fast path)."""
        self.aligner = LiveAligner(max_wait_s=self.config.max_wait_s, n_channels=n_aligned)
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
        self._init_ls()
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
        self._init_thrust_part()

    # ------------------------------------------------------------------ input
    def command(self, d: dict[str, Any], arrival: float | None = None) -> bool:
        """A decoded ``tpods.cmd/1`` message (received at host time ``arrival``, default
        its own time). Returns whether it was accepted."""
        self.counters.cmds_rx += 1
        if self.merger is not None:  # a structure: one of its modules
            if d.get("body") not in self.merger.index:
                self.counters.other_body += 1
                return False
            if arrival is not None and arrival > self._arrived:
                self._arrived = arrival
            for t, duty in self.merger.push(d["body"], d["t"], d["duty"], d.get("kind"), arrival):
                self._command(t, duty, None)
            if self.merger.end_t is not None:
                self.end_seen_t = self.merger.end_t
            return True
        if d.get("body") not in (None, self.body):
            self.counters.other_body += 1
            return False
        return self._command(d["t"], d["duty"], d.get("kind"))

    def _command(self, t: float, duty, kind: str | None) -> bool:
        """One command of the body (a structure: the merged 4N duties) into the aligner."""
        late_before = self.aligner.stats.cmds_late
        if self.structure is not None and self.z is None:
            # no live filter yet (it starts from the LS window): every command is still
            # usable by the fit and its catch-up
            self.aligner.rewind_floor = -math.inf
        else:
            self.aligner.rewind_floor = self._ck[0][0] if self._ck else math.inf
        if not self.aligner.push_command(t, duty):
            if self.aligner.stats.cmds_late > late_before:
                # too late for the live filter (it cannot rewrite the past), but the run
                # folder keeps it for post-processing
                if self.recorder is not None:
                    self.recorder.command(t, duty)
                if kind == "end":
                    self.end_seen_t = t
            return False
        try:
            if self.structure is not None:
                thrust = self.structure.virtual_thrust(np.asarray([duty], float), clamp=True)[0]
            else:
                thrust = self.table.thrust_n(np.asarray([duty], float), clamp=True)[0]
        except Exception:  # a duty the table cannot map (outside 0..100 never gets here)
            thrust = np.zeros(4)
        w = wrench(thrust, self.config.ekf.arm_m)
        self._wrench[float(t)] = (float(w[0]), float(w[1]), float(w[2]))
        if kind == "end":
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
        if arrival > self._arrived:
            self._arrived = arrival
        if d.get("body") not in (None, self.body):
            self.counters.other_body += 1
            return False
        t = d["t"]
        return self.aligner.push_pose(d["frame"], t, d["x"] if d["x"] is not None else math.nan,
                                      d["y"] if d["y"] is not None else math.nan,
                                      d["yaw"] if d["yaw"] is not None else math.nan,
                                      occluded=bool(d["occluded"]), arrival=min(t, arrival))

    def next_deadline(self) -> float | None:
        """Host time by which :meth:`process` must run again (a pose's wait ends, or a
        structure command's wait for its lagging modules)."""
        a = self.aligner.next_deadline()
        if self.merger is None:
            return a
        b = self.merger.next_deadline()
        return b if a is None else a if b is None else min(a, b)

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
        if self.structure is not None:
            return self._step_structure(z, P, t_prev, t, meas, use)
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

    # ------------------------------------------------------------ structures
    def _init_structure_filter(self) -> None:
        """The extended filter of a structure: mass, izz, cx, cy estimated (a cx or cy the
        structure's [body] gives as known is fixed; a [body] value with a sigma is a prior
        of the LS window's fit, as in ``tpods estimate batch``), the known terms of the
        EkfConfig fixed; the process noise of its first 8 states (added after every RK4
        step, as :func:`estimator.filters.ekf_ext.run_ext_ekf` does), none on cx, cy; the
        direct parameter form (the 1/m form was overconfident with cx, cy estimated, see
        estimator.estimate._extended_filter)."""
        cfg = self.config.ekf
        body = self.structure.body
        known, priors = body.known(), body.priors()
        if "mass" in known or "izz" in known:
            which = " and ".join(n for n in ("mass", "izz") if n in known)
            raise UserError(f"{self.structure.source}: [body] gives {which} as known (no sigma), "
                            "but the live filter always estimates mass and Izz; give it a sigma "
                            "(a prior), or post-process with `tpods estimate batch --method ls`")
        self._names = tuple(n for n in STRUCTURE_NAMES if n not in known)
        self._fixed = {"arm": cfg.arm_m, "ct": cfg.ct, "cr": cfg.cr, "kb": cfg.kb,
                       "ax": cfg.ax, "ay": cfg.ay}
        self._fixed.update({n: known[n] for n in ("cx", "cy") if n in known})
        self._priors = {n: priors[n] for n in self._names if n in priors}
        self._plant = filter_plant(self._names, self._fixed)
        self._q_nz = tuple((i, float(q)) for i, q in enumerate(cfg.q_psd) if q)
        self._off = _offset_spec(self._plant)
        guess = self.structure.initial_guess()
        self._guess = {k: guess[k] for k in self._names}

    def _prior_vector(self):
        """The [body] priors as ``(zbar, Pbar)`` over ``(x, y, psi, u, v, r, *names)`` for
        batch LS (other entries diffuse), or None."""
        if not self._priors:
            return None
        n = 6 + len(self._names)
        zbar, P = np.zeros(n), np.diag(np.full(n, np.inf))
        for j, name in enumerate(self._names):
            if name in self._priors:
                zbar[6 + j], P[6 + j, 6 + j] = self._priors[name][0], self._priors[name][1] ** 2
        return zbar, P

    def _com_index(self) -> list[int | None]:
        """State indices of cx, cy (None: fixed)."""
        return [6 + self._names.index(n) if n in self._names else None for n in ("cx", "cy")]

    def _step_structure(self, z, P, t_prev, t, meas, use):
        cfg = self.config.ekf
        if t_prev is not None and t > t_prev:
            seg_dt, seg_w = self._segments(t_prev, t)
            with np.errstate(over="ignore", invalid="ignore"):
                z, P, _ = _predict(z, P, seg_dt, seg_w, self._plant, self._q_nz, cfg.max_step_s,
                                   True)
        nis = math.nan
        if use and np.all(np.isfinite(z)) and np.all(np.isfinite(P)):
            z, P, (nis, _) = _update_offset(z, P, meas, self._R, self._off)
        return z, P, nis

    def com_m(self) -> tuple[float, float, np.ndarray] | None:
        """A structure's centre of mass (cx, cy, m, tracked frame) and its (2, 2) noise
        covariance, m^2 (0 for a fixed one; None before the first estimate or for a module)."""
        if self.structure is None or self.z is None:
            return None
        idx = self._com_index()
        c = [float(self.z[i]) if i is not None else float(self._fixed[n])
             for i, n in zip(idx, ("cx", "cy"), strict=True)]
        cov = np.zeros((2, 2))
        for a, ia in enumerate(idx):
            for b, ib in enumerate(idx):
                if ia is not None and ib is not None:
                    cov[a, b] = self.P[ia, ib]
        return c[0], c[1], cov

    def process(self, now: float) -> int:
        """Release the aligned poses, filter them, advance a catch-up, publish. Returns updates."""
        if self.merger is not None:
            # the stale wait runs on the arrival times of what was taken in, not the wall
            # clock: a backlog in the input queue must not make a row stale whose last
            # module's message is queued right behind
            for t, duty in self.merger.due(now if now == math.inf else min(now, self._arrived)):
                self._command(t, duty, None)
        if self._rewind_t is not None:
            self._rewind()
        ready = self.aligner.pop_ready(now)
        self.counters.max_backlog = max(self.counters.max_backlog, self.aligner.pending)
        n = 0
        for p in ready:
            meas = (p.x, p.y, p.yaw)
            if self.structure is not None and self.z is None:
                # a structure: no filter before the LS window's fit (see the class docstring)
                self.hist_t.append(p.t)
                self.hist_pose.append(meas)
                self.t_last, self.frame_last = p.t, p.frame
                self.counters.before_ls += 1
                if self.recorder is not None:
                    self.recorder.pose(p.t, p.x, p.y, p.yaw)
                n += 1
                continue
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
                com = None
                if self.structure is not None:
                    cx, cy, cc = self.com_m()
                    tc = np.diag(self.thrust_com_cov)
                    com = (cx, math.sqrt(max(cc[0, 0] + tc[0], 0.0)),
                           cy, math.sqrt(max(cc[1, 1] + tc[1], 0.0)))
                self.recorder.estimate(p.t, p.frame, self.phase, self.z,
                                       np.sqrt(np.maximum(self.P.diagonal(), 0.0)),
                                       self.thrust_rel, com)
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

    # ------------------------------------------------------ thrust uncertainty
    def _init_thrust_part(self) -> None:
        """The thrust table's part of the sigma, as fractions of m and Izz (issue 17).

        Until a consider covariance has been computed on this run's data it is the table's
        common ``scale_rel`` (exact for a common scale error: m and Izz move by the same
        fraction); the ls-ekf LS window and the end of the run (:meth:`finish`) replace it
        with the full consider covariance of the data so far, whose fractions are carried
        forward. A table without uncertainty gives 0 and ``thrust_note`` says so."""
        from estimator.batch.consider import NO_UNCERTAINTY

        t = self.table
        unc = getattr(t, "uncertainty", None)
        # a structure's modules may have different tables: no common fraction before a fit
        r = float(unc.scale_rel) if unc is not None and self.structure is None else 0.0
        self.thrust_rel = (r, r)
        self.thrust_com_cov = np.zeros((2, 2))
        """A structure's thrust part of the centre of mass's covariance, m^2 (absolute)."""
        if not self._states_uncertainty():
            self.thrust_note = NO_UNCERTAINTY
        elif r > 0:
            self.thrust_note = ("thrust part: the table's common scale_rel until a consider "
                                "covariance is computed on this run (LS window, end of run)")
        else:
            self.thrust_note = ("thrust part: none until a consider covariance is computed on "
                                "this run (LS window, end of run)")

    def _states_uncertainty(self) -> bool:
        src = self.structure if self.structure is not None else self.table
        return bool(getattr(src, "states_uncertainty", False))

    def _thrust_sensitivity(self, duty):
        """The table's thrust sensitivity of ``duty`` rows (a structure's: of its virtual
        thrusts), or None without uncertainty."""
        if not self._states_uncertainty():
            return None
        if self.structure is not None:
            return self.structure.virtual_sensitivity(duty, clamp=True)
        from common.thrust_uncertainty import thrust_sensitivity

        return thrust_sensitivity(self.table, duty, clamp=True)

    def _set_thrust_rel(self, res, where: str) -> None:
        """Carry a batch fit's thrust part forward as fractions of its m and Izz."""
        st = res.sigma_thrust
        im, ii = 6 + res.names.index("mass"), 6 + res.names.index("izz")
        rel = (float(st[im] / res.z0[im]), float(st[ii] / res.z0[ii]))
        if all(math.isfinite(v) and v >= 0 for v in rel):
            self.thrust_rel = rel
            if self.structure is not None and res.cov_thrust is not None:
                ct = np.zeros((2, 2))
                ic = [6 + res.names.index(n) if n in res.names else None for n in ("cx", "cy")]
                for a, ia in enumerate(ic):
                    for b, ib in enumerate(ic):
                        if ia is not None and ib is not None:
                            ct[a, b] = res.cov_thrust[ia, ib]
                self.thrust_com_cov = ct
            self.thrust_note = (f"{res.thrust_note}; the thrust part from the consider covariance "
                                f"of {where}, as fractions of m and Izz")

    def final_thrust_part(self) -> None:
        """The consider covariance of the whole run at its end: batch LS from the filter's
        estimate on every pose and command seen, then the table's consider term."""
        if self.z is None or not self._states_uncertainty() or len(self.hist_t) < 10:
            return
        from estimator.batch.consider import batch_consider
        from estimator.batch.least_squares import batch_ls

        cmd_t, duty = self.aligner.commands()
        sens = self._thrust_sensitivity(duty)
        start = {"mass": float(self.z[6]), "izz": float(self.z[7])}
        if self.structure is not None:
            cx, cy, _ = self.com_m()
            start.update({k: v for k, v in (("cx", cx), ("cy", cy)) if k in self._names})
        kw = self._ls_kwargs(start)
        try:
            res = batch_ls(np.asarray(self.hist_t), np.asarray(self.hist_pose), cmd_t,
                           sens.thrust_n, **kw)
            if not res.converged:
                return
            c = batch_consider(res, cmd_t, sens, sigma_pos_m=kw["sigma_pos_m"],
                               sigma_yaw_rad=kw["sigma_yaw_rad"])
        except Exception:  # the end of a run never fails on this; the last fractions stay
            return
        if np.all(np.isfinite(c.cov_thrust)):
            res.add_thrust_covariance(c.cov_thrust, c.names)
            res.thrust_note = "sigma = measurement noise + thrust table uncertainty"
            self._set_thrust_rel(res, "the whole run")

    def _sigmas(self, m: float, sm: float, izz: float, si: float) -> tuple[float, ...]:
        """(mass total, izz total, mass noise, mass thrust, izz noise, izz thrust) sigmas."""
        tm, ti = abs(m) * self.thrust_rel[0], abs(izz) * self.thrust_rel[1]
        return math.hypot(sm, tm), math.hypot(si, ti), sm, tm, si, ti

    # ---------------------------------------------------------------- output
    def estimate(self, now: float | None = None) -> dict[str, Any] | None:
        """The current estimate message (None before the first update)."""
        if self.z is None:
            return None
        z = self.z
        sig = np.sqrt(np.maximum(self.P.diagonal(), 0.0))
        sm, si, nm, tm, ni, ti = self._sigmas(float(z[6]), float(sig[6]), float(z[7]), float(sig[7]))
        out = {
            "schema": EST_SCHEMA, "body": self.body, "seq": self._seq,
            "t": self.t_last, "frame": self.frame_last,
            "t_pub": time.time() if now is None else now,
            "method": self.config.method, "phase": self.phase,
            "mass_kg": float(z[6]), "mass_sigma_kg": sm,
            "izz_kgm2": float(z[7]), "izz_sigma_kgm2": si,
            "mass_sigma_noise_kg": nm, "mass_sigma_thrust_kg": tm,
            "izz_sigma_noise_kgm2": ni, "izz_sigma_thrust_kgm2": ti,
            "state": dict(zip(STATE_NAMES[:6], z[:6].tolist(), strict=True)),
            "state_sigma": dict(zip(STATE_NAMES[:6], sig[:6].tolist(), strict=True)),
            "n_updates": self.counters.updates,
            "nis": None if math.isnan(self.last_nis) else float(self.last_nis),
            "diverged": self.diverged,
            "inconsistent": self.inconsistent,
        }
        if self.structure is not None:
            out.update(self._com_keys())
        return out

    def _com_keys(self) -> dict[str, Any]:
        """A structure's centre of mass (tracked frame, m): total sigmas (noise + thrust
        table), their parts, the (2, 2) total covariance ``cov_com_m2`` and Izz about the
        tracked origin (kg m^2; its sigma from the noise covariance of m, Izz, cx, cy and
        the thrust parts of m and Izz, first order)."""
        z, P = self.z, self.P
        cx, cy, cn = self.com_m()
        ct = self.thrust_com_cov
        cov = cn + ct
        m, izz = float(z[6]), float(z[7])
        g = np.zeros(len(z))
        g[6], g[7] = cx * cx + cy * cy, 1.0
        for i, v in zip(self._com_index(), (2 * m * cx, 2 * m * cy), strict=True):
            if i is not None:
                g[i] = v
        # the thrust part of m and Izz added linearly: exact for a common scale error (m and
        # Izz move together), conservative otherwise
        t_o = abs(g[6] * m * self.thrust_rel[0]) + abs(izz * self.thrust_rel[1])
        var_o = float(g @ P @ g) + t_o * t_o
        sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
        return {"structure": self.structure.name,
                "com_x_m": cx, "com_x_sigma_m": float(sd[0]),
                "com_y_m": cy, "com_y_sigma_m": float(sd[1]),
                "com_x_sigma_noise_m": math.sqrt(max(cn[0, 0], 0.0)),
                "com_y_sigma_noise_m": math.sqrt(max(cn[1, 1], 0.0)),
                "com_x_sigma_thrust_m": math.sqrt(max(ct[0, 0], 0.0)),
                "com_y_sigma_thrust_m": math.sqrt(max(ct[1, 1], 0.0)),
                "cov_com_m2": cov.tolist(),
                "izz_origin_kgm2": izz + m * (cx * cx + cy * cy),
                "izz_origin_sigma_kgm2": math.sqrt(max(var_o, 0.0))}

    def _publish(self, now: float) -> None:
        self._last_pub = now
        if self.z is None or (self.publish is None and self.publish_bytes is None):
            return
        self._seq += 1
        try:
            if self.publish_bytes is not None:
                if self.structure is not None:  # the extra keys: the general encoder
                    msg = self.estimate()
                    msg["seq"] = self._seq
                    self.publish_bytes(encode_estimate(msg))
                else:
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
        sm, si, nm, tm, ni, ti = self._sigmas(z[6], sg[6], z[7], sg[7])
        return (_EST_FMT % (self._body_json, self._seq, self.t_last, self.frame_last, time.time(),
                            self.config.method, self.phase, z[6], sm, z[7], si, nm, tm, ni, ti,
                            *z[:6], *sg[:6], self.counters.updates, nis,
                            "true" if self.diverged else "false",
                            "true" if self.inconsistent else "false")).encode()

    def finish(self) -> dict[str, Any] | None:
        """End of stream: release every pending pose, finish an ls-ekf restart, publish."""
        self.process(math.inf)
        if self.config.method == "ls-ekf":
            if self.phase == "ekf" and self.hist_t and (
                    self.hist_t[-1] - self.hist_t[0] >= self.config.ls_window_s
                    or (self.structure is not None and len(self.hist_t) >= 10)):
                # (a structure has no estimate but the LS one: a run shorter than the
                # window is fitted whole)
                self._start_ls()
            self._ls_tick(block=True)
            self.close_pool()
        self.final_thrust_part()
        self._publish(time.time())
        return self.estimate()

    def stats(self) -> dict[str, Any]:
        d = asdict(self.counters)
        d.update({f"align_{k}": v for k, v in self.aligner.stats.as_dict().items()})
        d["pending"] = self.aligner.pending
        if self.merger is not None:
            d.update({f"merge_{k}": v for k, v in self.merger.stats.as_dict().items()})
        return d

    def summary(self) -> dict[str, Any]:
        """Final estimate, phase, LS details and counters (JSON-ready)."""
        est = self.estimate() or {}
        out = {k: est.get(k) for k in ("method", "phase", "mass_kg", "mass_sigma_kg", "izz_kgm2",
                                       "izz_sigma_kgm2", "mass_sigma_noise_kg",
                                       "mass_sigma_thrust_kg", "izz_sigma_noise_kgm2",
                                       "izz_sigma_thrust_kgm2", "state", "state_sigma",
                                       "n_updates", "diverged", "inconsistent")}
        out["thrust_uncertainty"] = {"included": self._states_uncertainty(),
                                     "note": self.thrust_note}
        if self.structure is not None:
            out["structure"] = self.structure.name
            out["modules"] = [m.name for m in self.structure.modules]
            out.update({k: est.get(k) for k in (
                "com_x_m", "com_x_sigma_m", "com_y_m", "com_y_sigma_m", "com_x_sigma_noise_m",
                "com_y_sigma_noise_m", "com_x_sigma_thrust_m", "com_y_sigma_thrust_m",
                "cov_com_m2", "izz_origin_kgm2", "izz_origin_sigma_kgm2")})
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


