"""The live estimator core: align, filter and publish, without any network code.

:class:`LiveEstimator`: feed it decoded pose and command messages
(:meth:`~LiveEstimator.pose`, :meth:`~LiveEstimator.command`) and call
:meth:`~LiveEstimator.process` with the host time; it aligns them
(:class:`estimator.live.align.LiveAligner`: commands are a zero-order hold, a pose is
filtered as it arrives unless ``max_wait_s`` > 0 makes it wait for a late command,
occluded / non-finite / repeated / too-old samples are counted and skipped), runs the lean
EKF (:func:`estimator.filters.ekf.ekf_predict`, :func:`estimator.filters.ekf.ekf_update`)
pose by pose, re-runs the poses since a checkpoint when a command arrives after poses it
governs (``rewind_s``; their estimates then carry ``rev`` > 0, and with
``publish_rate_hz`` 0 are published again), and hands estimate messages to ``publish`` at
``publish_rate_hz`` (0: after every update).

Its parts, each in its module (mixins of :class:`LiveEstimator`):

- :mod:`estimator.live.config`: :class:`LiveConfig`, its defaults, :class:`LiveCounters`;
- :mod:`estimator.live.restart`: the ``ls-ekf`` start (batch LS on the first window) and the
  catch-up and takeover of the second filter;
- :mod:`estimator.live.history`: checkpoints and the rewind, the estimate history, the
  recent NIS and the ``diverged`` / ``inconsistent`` tests;
- :mod:`estimator.live.structure_filter`: a structure's filter (mass, Izz, centre of mass);
- :mod:`estimator.live.thrust_part`: thrusts of duty rows, the thrust table's part of the sigma;
- :mod:`estimator.live.messages`: the estimate message, publishing, stats and summary.

The names of :mod:`estimator.live.config` and :mod:`estimator.live.history` that this module
held before are importable from here too.
"""

from __future__ import annotations

import bisect
import json
import math
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from common.errors import UserError
from estimator.filters.kernels import ekf_predict, ekf_update
from estimator.live.align import LiveAligner
from estimator.live.clock_apply import OffsetApplier
from estimator.live.clock_offset import OffsetMeter
from estimator.live.config import (
    DEFAULT_MAX_WAIT_S,
    DEFAULT_REWIND_S,
    LIVE_METHODS,
    LiveConfig,
    LiveCounters,
)
from estimator.live.gaps import GapTracker, forget_motion
from estimator.live.history import DIVERGED_NIS, NIS_WINDOW, LiveHistory
from estimator.live.history import _nis_limits as _nis_limits
from estimator.live.merge import ModuleMerger
from estimator.live.messages import EstimateMessages
from estimator.live.restart import LsEkfRestart
from estimator.live.structure_filter import STRUCTURE_NAMES, StructureFilter
from estimator.live.thrust_part import ThrustPart
from estimator.plant.model import wrench

if TYPE_CHECKING:
    from common.structure import Structure
    from estimator.live.recorder import LiveRecorder

__all__ = [
    "DEFAULT_MAX_WAIT_S", "DEFAULT_REWIND_S", "DIVERGED_NIS", "LIVE_METHODS", "NIS_WINDOW",
    "STRUCTURE_NAMES", "LiveConfig", "LiveCounters", "LiveEstimator",
]

_ZERO_W = (0.0, 0.0, 0.0)


class LiveEstimator(LsEkfRestart, LiveHistory, StructureFilter, ThrustPart, EstimateMessages):
    """Align, filter and publish (no network code; see the module docstring).

    Args:
        table: thrust table used by the estimator (duty percent to newtons).
        config: :class:`LiveConfig`.
        body: the body name (estimate messages, sanity check of incoming messages).
        publish: called with each estimate message (a dict).
        recorder: optional :class:`LiveRecorder`.
        structure: a :class:`common.structure.Structure`: the commands come
            from its modules (each message's ``body`` a module name, four duties), merged
            into the structure's 4N duties (:class:`estimator.live.merge.ModuleMerger`);
            the thrusts are its virtual thrusts; the unknowns are mass, Izz about the
            centre of mass and the centre of mass (cx, cy) in the tracked frame, with the
            extended filter's offset-aware pose update in the direct parameter form (as
            ``tpods estimate batch --method ls-ekf`` on a structure run). Only ``ls-ekf``:
            no estimate is made before the LS window's fit (from the structure's
            geometric start the EKF alone diverges; docs/estimators.md). ``table`` is then
            unused (give the structure its tables). A :class:`common.vehicle.Vehicle`
            is taken the same way, its N duties on the body's one command
            stream (``config.n_channels`` = N), its valve timing in the hold segments.
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
                raise UserError(f"a {structure.kind} is estimated live with --method ls-ekf only: "
                                "from its geometric start the EKF alone diverges "
                                "(docs/estimators.md)")
            if structure.kind == "structure":  # a vehicle's N duties come on one stream
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
        self.gaps = GapTracker(csv_path=None if recorder is None else recorder.out / "gaps.csv")
        self.clock_meter = OffsetMeter()
        self.clock_apply = OffsetApplier(enabled=self.config.clock_offset_auto)
        self._clock_windows = 0
        self.on_note: Callable[[str], None] | None = None
        self.clock_ping: dict[str, Any] | None = None
        """The round-trip measurement of the player host's clock (set by the caller)."""
        """Called once with a line when a measured clock offset is applied (stderr)."""
        self._wrench: dict[float, tuple[float, float, float]] = {}
        self.z: np.ndarray | None = None
        self.P: np.ndarray | None = None
        self.t_last: float | None = None
        self.frame_last = -1
        self.last_nis = math.nan
        self.phase = "ekf"
        self.hist_t: list[float] = []
        self.hist_pose: list[tuple[float, float, float]] = []
        self.hist_frame: list[int] = []
        """Frame numbers of the poses in ``hist_t`` (the estimates published again after a
        rewind name them)."""
        self.rev_last = 0
        """Revision of the current estimate: how many times the filter re-ran its pose."""
        self._init_ls()
        self.restart_t: float | None = None
        self.end_seen_t: float | None = None
        self._last_pub = -math.inf
        self._seq = 0
        self._init_history()
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
        self._input_gap(self.gaps.command(self.body, d.get("seq"), d["t"],
                                          d["t"] if arrival is None else arrival))
        if arrival is not None:
            self.clock_meter.command(d["t"], arrival)
            self.clock_apply.command(d["t"], arrival)
        return self._command(d["t"], d["duty"], d.get("kind"))

    def _command(self, t: float, duty, kind: str | None) -> bool:
        """One command of the body (a structure: the merged 4N duties) into the aligner."""
        late_before = self.aligner.stats.cmds_late
        before = self.aligner.duty_in_force(t)
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
            thrust = self._thrust_of(np.asarray([duty], float))[0]
        except Exception:  # a duty the table cannot map (outside 0..100 never gets here)
            thrust = np.zeros(4)
        w = wrench(thrust, self.config.ekf.arm_m)
        self._wrench[float(t)] = (float(w[0]), float(w[1]), float(w[2]))
        if kind == "end":
            self.end_seen_t = t
        if self.recorder is not None:
            self.recorder.command(t, duty)
        changes = before is None or before != self.aligner.duty_in_force(t)
        if not changes:  # a hold (or a repeat) of the duty in force: nothing to correct
            self.counters.cmds_no_change += 1
        elif self.t_last is not None and t < self.t_last:
            # the filter already went past it: re-filter from before it (in process()); a
            # command stamped at the last pose's time acts only after that pose
            self._rewind_t = t if self._rewind_t is None else min(self._rewind_t, t)
        cu = self._cu
        if changes and cu is not None and cu["t"] is not None and t <= cu["t"]:  # the catch-up too
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
        t0 = d["t"] - self.config.clock_offset_s  # on the player's clock (as given)
        self.clock_meter.pose(t0, arrival)
        self._clock_settle(arrival)
        t, in_overlap = self.clock_apply.pose_time(t0, arrival)  # (as measured, once applied)
        self.gaps.pose(d["frame"], t, arrival)
        if in_overlap:
            return False
        return self.aligner.push_pose(d["frame"], t, d["x"] if d["x"] is not None else math.nan,
                                      d["y"] if d["y"] is not None else math.nan,
                                      d["yaw"] if d["yaw"] is not None else math.nan,
                                      occluded=bool(d["occluded"]), arrival=min(t, arrival))

    def _clock_settle(self, arrival: float) -> None:
        """A new window of the clock meter: apply its offset once it has settled
        (:mod:`estimator.live.clock_apply`), and say so once."""
        n = len(self.clock_meter.samples)
        if n == self._clock_windows:
            return
        self._clock_windows = n
        self.clock_apply.consider(self.clock_meter.estimate(), arrival)
        if self.clock_apply.take_news() and self.on_note is not None:
            self.on_note(self.clock_apply.message())

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
        ts = self.aligner.switch_times(t0, t1)
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

    def _step(self, z, P, t_prev: float | None, t: float, meas, use: bool = True, k: int = 0):
        """Predict from ``t_prev`` to ``t`` (s) and update with ``meas`` (x, y m, yaw rad), the
        pose ``hist_t[k]``: its covariance is symmetrised on every 16th pose as the batch
        filter does (:func:`estimator.filters.loop.run_filter`), so both give the same
        numbers on the same data."""
        cfg = self.config.ekf
        if self.structure is not None:
            return self._step_structure(z, P, t_prev, t, meas, use)
        if t_prev is not None and t > t_prev:
            seg_dt, seg_w = self._segments(t_prev, t)
            z, P, _ = ekf_predict(z, P, seg_dt, seg_w, cfg)
            if self.gaps.input_unknown(t_prev, t):
                self._forget_motion(P, t - t_prev, z)
        nis = math.nan
        if use:
            z, P, (nis, _) = ekf_update(z, P, meas, cfg, self._R, (k & 15) == 0)
        return z, P, nis

    def _input_gap(self, gap) -> None:
        """Commands were lost: the filter re-runs from before the gap (if it went past its
        start within the rewind horizon) and takes the input there as unknown
        (:func:`estimator.live.gaps.forget_motion`); beyond the horizon it forgets the
        motion now."""
        if gap is None or gap.missing == 0 or self.z is None or self.structure is not None:
            return
        if self.t_last is not None and self.t_last > gap.t_start:
            if self._ck and self._ck[0][0] <= gap.t_start:
                self._rewind_t = (gap.t_start if self._rewind_t is None
                                  else min(self._rewind_t, gap.t_start))
            else:
                self._forget_motion(self.P, gap.t_end - gap.t_start, self.z)

    def _forget_motion(self, P, dt_s: float, z) -> None:
        """:func:`~estimator.live.gaps.forget_motion` with full thrust's accelerations at
        the filter's mass and Izz (every valve at 100 %: m/s^2, rad/s^2)."""
        full = np.abs(self._thrust_of(np.full((1, self.config.n_channels), 100.0))[0])
        f = float(np.sum(full))
        m, izz = max(float(z[6]), 1e-3), max(float(z[7]), 1e-6)
        forget_motion(P, self.config.ekf.P0, dt_s, f / m, f * self.config.ekf.arm_m / izz)
        self.counters.motion_resets += 1

    def _start_filter(self, meas) -> None:
        z = np.array(self.config.ekf.x0, dtype=float)
        z[:3] = meas
        self.z, self.P = z, self.config.ekf.P0.copy()

    # ------------------------------------------------------------- the stream
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
                self.hist_frame.append(p.frame)
                self.t_last, self.frame_last = p.t, p.frame
                self.counters.before_ls += 1
                if self.recorder is not None:
                    self.recorder.pose(p.t, p.x, p.y, p.yaw)
                n += 1
                continue
            k = len(self.hist_t)
            if self.z is None:
                self._start_filter(meas)
                self.z, self.P, self.last_nis = self._step(self.z, self.P, None, p.t, meas, k=k)
            else:
                self.z, self.P, self.last_nis = self._step(self.z, self.P, self.t_last, p.t, meas,
                                                           k=k)
            self.t_last = p.t
            self.frame_last = p.frame
            self.rev_last = 0
            self.hist_t.append(p.t)
            self.hist_pose.append(meas)
            self.hist_frame.append(p.frame)
            self.counters.updates += 1
            n += 1
            self._after_update(p.t, len(self.hist_t) - 1)
            if self.config.publish_rate_hz == 0:
                self._publish(now)  # the estimate out first, the run folder's rows after it
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
        if self.config.method == "ls-ekf":
            self._ls_tick()
        if n and self.config.publish_rate_hz > 0 and now - self._last_pub >= 1.0 / self.config.publish_rate_hz:
            self._publish(now)
        return n

    def finish(self) -> dict[str, Any] | None:
        """End of stream: release every pending pose (the recording is then whole and sealed:
        :meth:`LiveRecorder.seal`), finish an ls-ekf restart, the final fit, publish."""
        self.process(math.inf)
        if self.recorder is not None:
            self.recorder.seal()
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

