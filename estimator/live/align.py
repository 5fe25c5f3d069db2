"""Align a live pose stream with a live command stream (pure logic, no I/O).

Commands are a zero-order hold: a pose at time ``t`` can be filtered once the
command in force over ``(t_prev, t]`` is known. Commands travel on their own
channel and may arrive after the poses they govern, so a pose waits until a
command stamped at or after its time has arrived, or until it has waited
``max_wait_s`` (then the latest command is taken to still hold).

Bad or useless samples are counted and skipped, never used: occluded or
non-finite poses, repeated frames, poses older than the last released one,
commands older than the last released pose (they would rewrite the past) unless the
consumer can still re-filter from before them (``rewind_floor``).
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field

import numpy as np

from estimator.live.counters import Counters

PRESTART_KEEP_S = 0.5
"""Before any command has arrived, a pose waits up to this long (host seconds) for the
first command, which may be stamped at or before it; then it is dropped and counted
(``before_first_cmd``). Nothing can be filtered before the first command, so the wait
costs no latency."""


@dataclass(frozen=True)
class Pose:
    """One pose sample: frame number, capture time (s, host clock), x, y (m), yaw (rad)."""

    frame: int
    t: float
    x: float
    y: float
    yaw: float


@dataclass
class AlignStats(Counters):
    poses_in: int = 0
    poses_out: int = 0
    occluded: int = 0
    non_finite: int = 0
    duplicates: int = 0
    too_old: int = 0
    cmds_in: int = 0
    cmds_late: int = 0
    cmds_rewound: int = 0
    cmds_bad: int = 0
    released_by_timeout: int = 0
    before_first_cmd: int = 0


@dataclass
class LiveAligner:
    """Buffer poses until the commands governing them are known.

    Args:
        max_wait_s: longest a pose waits (host clock) for a command stamped at or
            after its time before the latest command is assumed to still hold.
        n_channels: number of valves in a command.

    ``rewind_floor`` (host time, default +inf: never) is set by a consumer that can
    re-filter released poses: a command older than the last released pose but newer
    than this floor is accepted (counted in ``cmds_rewound``) and the consumer re-runs
    its filter from before it; older ones are refused (``cmds_late``).
    """

    max_wait_s: float = 0.05
    n_channels: int = 4
    stats: AlignStats = field(default_factory=AlignStats)
    rewind_floor: float = math.inf

    def __post_init__(self) -> None:
        self._cmd_t: list[float] = []
        self._cmd_d: list[tuple[float, ...]] = []
        self._pending: list[tuple[float, int, Pose, float]] = []  # (t, frame, pose, arrival)
        self._seen_frames: set[int] = set()
        self._released_t = -math.inf

    # ------------------------------------------------------------------ input
    def push_command(self, t: float, duty_pct) -> bool:
        """Add a command (host time ``t``, duty percent per channel). Returns False if skipped."""
        try:
            d = tuple(float(x) for x in duty_pct)
            t = float(t)
        except (TypeError, ValueError):
            self.stats.cmds_bad += 1
            return False
        if len(d) != self.n_channels or not math.isfinite(t) or not all(
                math.isfinite(x) and 0.0 <= x <= 100.0 for x in d):
            self.stats.cmds_bad += 1
            return False
        if t <= self._released_t:
            if t <= self.rewind_floor:
                self.stats.cmds_late += 1
                return False
            self.stats.cmds_rewound += 1
        self.stats.cmds_in += 1
        i = bisect.bisect_right(self._cmd_t, t)
        if i > 0 and self._cmd_t[i - 1] == t:
            self._cmd_d[i - 1] = d  # same stamp: the later message wins
            return True
        self._cmd_t.insert(i, t)
        self._cmd_d.insert(i, d)
        return True

    def push_pose(self, frame: int, t: float, x: float, y: float, yaw: float,
                  occluded: bool = False, arrival: float | None = None) -> bool:
        """Add a pose; ``arrival`` is the host time it arrived (default: ``t``)."""
        self.stats.poses_in += 1
        if occluded:
            self.stats.occluded += 1
            return False
        vals = (t, x, y, yaw)
        if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in vals):
            self.stats.non_finite += 1
            return False
        if frame in self._seen_frames:
            self.stats.duplicates += 1
            return False
        if t <= self._released_t:
            self.stats.too_old += 1
            return False
        self._seen_frames.add(frame)
        if len(self._seen_frames) > 100_000:  # bounded memory on long runs
            cutoff = frame - 50_000
            self._seen_frames = {f for f in self._seen_frames if f > cutoff}
        bisect.insort(self._pending, (float(t), int(frame), Pose(int(frame), float(t), float(x),
                                                                  float(y), float(yaw)),
                                      float(t if arrival is None else arrival)))
        return True

    # ----------------------------------------------------------------- output
    def pop_ready(self, now: float) -> list[Pose]:
        """Poses (in time order) whose governing commands are known at host time ``now``."""
        out: list[Pose] = []
        latest_cmd = self._cmd_t[-1] if self._cmd_t else -math.inf
        while self._pending:
            t, _, pose, arrival = self._pending[0]
            if not self._cmd_t:
                # nothing commanded yet: the first command may still come stamped at or before
                # this pose (it waits up to PRESTART_KEEP_S for it, however short max_wait_s)
                if now - arrival >= max(self.max_wait_s, PRESTART_KEEP_S):
                    self._pending.pop(0)
                    self.stats.before_first_cmd += 1
                    continue
                break
            if t < self._cmd_t[0]:  # before the first command: the pose cannot be used
                self._pending.pop(0)
                self.stats.before_first_cmd += 1
                continue
            if latest_cmd >= t:
                pass
            elif now - arrival >= self.max_wait_s:
                self.stats.released_by_timeout += 1
            else:
                break
            self._pending.pop(0)
            self._released_t = t
            self.stats.poses_out += 1
            out.append(pose)
        return out

    def flush(self) -> list[Pose]:
        """Release every pending pose (end of stream)."""
        return self.pop_ready(math.inf)

    @property
    def pending(self) -> int:
        """Number of poses waiting for their command."""
        return len(self._pending)

    def next_deadline(self) -> float | None:
        """Host time at which the oldest pending pose is released by timeout (None: none pending)."""
        if not self._pending:
            return None
        wait = self.max_wait_s if self._cmd_t else max(self.max_wait_s, PRESTART_KEEP_S)
        return self._pending[0][3] + wait

    # --------------------------------------------------------------- commands
    @property
    def first_command_t(self) -> float | None:
        return self._cmd_t[0] if self._cmd_t else None

    def duty_in_force(self, t: float) -> tuple[float, ...] | None:
        """The duties (%) of the last command stamped at or before ``t`` (s); None before
        the first."""
        i = bisect.bisect_right(self._cmd_t, t) - 1
        return self._cmd_d[i] if i >= 0 else None

    def commands(self) -> tuple[np.ndarray, np.ndarray]:
        """All commands so far: (N,) times and (N, n_channels) duties."""
        return (np.asarray(self._cmd_t, dtype=float),
                np.asarray(self._cmd_d, dtype=float).reshape(-1, self.n_channels))

    def switch_times(self, t0: float, t1: float) -> list[float]:
        """The times of :meth:`commands_between` as a list (no arrays: the live filter's
        every step)."""
        cmd_t = self._cmd_t
        ts = cmd_t[max(bisect.bisect_right(cmd_t, t0) - 1, 0):bisect.bisect_right(cmd_t, t1)]
        if ts and ts[0] < t0:
            ts[0] = t0
        return ts

    def commands_between(self, t0: float, t1: float) -> tuple[np.ndarray, np.ndarray]:
        """The command in force at ``t0`` (restamped to ``t0``) and every switch in (t0, t1]."""
        i0 = max(bisect.bisect_right(self._cmd_t, t0) - 1, 0)
        i1 = bisect.bisect_right(self._cmd_t, t1)
        t = np.asarray(self._cmd_t[i0:i1], dtype=float)
        d = np.asarray(self._cmd_d[i0:i1], dtype=float).reshape(-1, self.n_channels)
        if len(t):
            t[0] = max(t[0], t0)
        return t, d
