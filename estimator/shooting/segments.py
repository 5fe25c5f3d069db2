"""Where a run is cut into shooting segments.

A segment is a stretch of consecutive poses that the model must predict from one initial
state of its own. Segments never cross a gap in the poses (an interval far longer than
the run's typical one), a reset (a pose that jumps further than the body can move in one
interval), or an excluded time range (``--exclude T0:T1``, or an event found in the run).
Each stretch between such breaks is cut into pieces of about the segment length; a piece
with too few poses to fix its six initial states and inform the shared parameters is left
out and counted.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from common.errors import UserError

GAP_FACTOR = 5.0
"""An interval longer than this many times the median one (and than 0.25 s) is a gap."""

JUMP_M = 0.25
"""A pose that moves further than this in one interval (faster than 5 m/s at 20 Hz) is a reset."""

JUMP_RAD = 1.0
"""A yaw that turns further than this in one interval is a reset."""

MIN_POSES = 8
"""Fewest poses in a segment (three per pose, six initial states to fix)."""


@dataclass(frozen=True)
class SegmentPlan:
    """Segments as ``[start, stop)`` pose-index ranges, in time order.

    Attributes:
        bounds: (S, 2) int index ranges into the run's poses.
        length_s: the segment length asked for, s (inf: single shooting).
        breaks: ``(t, why)`` of every break that is not a plain cut (gap, reset).
        excluded: ``(t0, t1, why)`` of every excluded time range, in run seconds.
        dropped: the number of pieces left out as too short.
    """

    bounds: np.ndarray
    length_s: float
    breaks: list[tuple[float, str]] = field(default_factory=list)
    excluded: list[tuple[float, float, str]] = field(default_factory=list)
    dropped: int = 0

    @property
    def n(self) -> int:
        return len(self.bounds)

    def labels(self, n_poses: int) -> np.ndarray:
        """(n_poses,) the segment of each pose, -1 for a pose in none."""
        out = np.full(n_poses, -1)
        for s, (a, b) in enumerate(self.bounds):
            out[a:b] = s
        return out


def parse_segments(text: str | None) -> float | None:
    """``--segments``: ``"5s"``, ``"5"`` (seconds), ``"none"`` (single shooting: inf) or
    ``"auto"``/None (chosen from the data: None)."""
    if text is None or text.strip().lower() in ("", "auto"):
        return None
    t = text.strip().lower()
    if t in ("none", "single", "off"):
        return math.inf
    try:
        v = float(t[:-1] if t.endswith("s") else t)
    except ValueError:
        raise UserError(f"--segments {text}: give a length in seconds (5s), none or auto") from None
    if not (math.isfinite(v) and v > 0):
        raise UserError(f"--segments {text}: the length must be a positive number of seconds")
    return v


def parse_excludes(texts: Sequence[str] | None) -> list[tuple[float, float]]:
    """``--exclude T0:T1`` (repeatable) -> [(t0, t1)] in run seconds."""
    out = []
    for text in texts or ():
        parts = text.replace(",", ":").split(":")
        try:
            t0, t1 = (float(p) for p in parts)
        except ValueError:
            raise UserError(f"--exclude {text}: give T0:T1 in seconds (e.g. 30:42.5)") from None
        if not (math.isfinite(t0) and math.isfinite(t1) and t1 > t0):
            raise UserError(f"--exclude {text}: T1 must be after T0")
        out.append((t0, t1))
    return out


def plan_segments(pose_t: np.ndarray, pose: np.ndarray, length_s: float,
                  exclude: Sequence[tuple[float, float, str]] = (),
                  min_poses: int = MIN_POSES) -> SegmentPlan:
    """Cut the poses ``(pose_t (N,), pose (N, 3))`` into segments of about ``length_s``.

    ``exclude`` holds ``(t0, t1, why)`` in the same seconds as ``pose_t`` (relative to the
    run's start); poses inside a range belong to no segment.
    """
    t = np.asarray(pose_t, float)
    p = np.asarray(pose, float)
    n = len(t)
    if n < min_poses:
        raise UserError(f"{n} poses: too few to fit (at least {min_poses})")
    dt = np.diff(t)
    med = float(np.median(dt))
    gap = dt > max(GAP_FACTOR * med, 0.25)
    step = np.hypot(np.diff(p[:, 0]), np.diff(p[:, 1]))
    turn = np.abs(np.angle(np.exp(1j * np.diff(p[:, 2]))))
    reset = (step > JUMP_M) | (turn > JUMP_RAD)
    breaks = [(float(t[i + 1]), "gap" if gap[i] else "reset")
              for i in np.nonzero(gap | reset)[0]]
    keep = np.ones(n, bool)
    for t0, t1, _ in exclude:
        keep &= ~((t >= t0) & (t <= t1))
    # a new stretch starts after every gap or reset and after every excluded pose
    starts_new = np.zeros(n, bool)
    starts_new[1:] = gap | reset
    stretches: list[tuple[int, int]] = []
    a = None
    for i in range(n):
        if not keep[i]:
            if a is not None:
                stretches.append((a, i))
            a = None
            continue
        if a is None:
            a = i
        elif starts_new[i]:
            stretches.append((a, i))
            a = i
    if a is not None:
        stretches.append((a, n))
    bounds: list[tuple[int, int]] = []
    dropped = 0
    for a, b in stretches:
        span = float(t[b - 1] - t[a])
        pieces = 1 if not math.isfinite(length_s) else max(1, int(round(span / length_s)))
        cuts = np.searchsorted(t[a:b], t[a] + span * np.arange(1, pieces) / pieces) + a
        edges = [a, *cuts.tolist(), b]
        for i0, i1 in zip(edges[:-1], edges[1:], strict=True):
            if i1 - i0 >= min_poses:
                bounds.append((i0, i1))
            else:
                dropped += 1
    if not bounds:
        raise UserError("no stretch of the run is long enough to fit (every piece between gaps, "
                        f"resets and excluded ranges has fewer than {min_poses} poses)")
    return SegmentPlan(np.array(bounds, int), float(length_s), breaks,
                       [(float(a), float(b), str(w)) for a, b, w in exclude], dropped)
