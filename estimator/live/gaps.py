"""Gaps in the live streams, named (pure logic but the optional CSV; no network code).

A lab network can cut a host off for seconds: the poses then stop, and either come later
all at once (a TCP link holds them and replays them after the heal: none missing) or never
(a router restarted: they were dropped). Commands likewise. :class:`GapTracker` watches
both streams and names every gap instead of letting the filter bridge it silently:

- **pose gaps**: between two consecutive poses received (frame numbers in order), frames
  missing (``missing`` > 0), or no pose at all for longer than ``silence_s`` host seconds
  (``silent_s``; the poses came late, none missing);
- **command gaps**: the player numbers every message (``seq``); a jump means commands
  were lost (``missing``), so the valves' input between the last command before and the
  first after is *unknown*. :meth:`GapTracker.input_unknown` tells the filter which
  intervals those are: it must not take a held command for the truth there.

Each gap is a :class:`Gap`; ``rows()`` gives them for the summary (``gaps`` in the
``--json`` output and run.json) and ``gaps.csv`` is written as they are found.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

GAP_COLUMNS = ("stream", "t_start", "t_end", "duration_s", "missing", "silent_s",
               "frame_before", "frame_after", "host_end")
"""gaps.csv: ``t_start``/``t_end`` lab times (s) of the last message before and the first
after; ``frame_*`` the poses' frame numbers (commands: their seq); ``host_end`` the host
time (s) the first message after arrived."""
DEFAULT_SILENCE_S = 0.5
"""Host seconds without a pose (or a command) after which the pause is named a gap even if
nothing turns out missing (the player re-announces its command every 0.1 s)."""


@dataclass(frozen=True)
class Gap:
    """One gap of a stream ("poses" or "commands").

    ``t_start``/``t_end``: lab times (s) of the last message received before it and the
    first after; ``missing``: messages never received between them; ``silent_s``: host
    seconds between their arrivals; ``before``/``after``: their frame numbers (poses) or
    sequence numbers (commands); ``host_end``: host time (s) the first one after arrived."""

    stream: str
    t_start: float
    t_end: float
    missing: int
    silent_s: float
    before: int
    after: int
    host_end: float

    @property
    def duration_s(self) -> float:
        return self.t_end - self.t_start

    def as_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["duration_s"] = self.duration_s
        return d



def gap_sentence(g: dict[str, Any], t0: float | None = None) -> str:
    """A gap row (:meth:`Gap.as_dict`) in words, times from ``t0`` (lab s):
    ``poses: gap 3.02-5.11 s (2.09 s), 209 missing``."""
    t0 = 0.0 if t0 is None else t0
    what = (f"{g['missing']} missing" if g["missing"]
            else f"none missing, {g['silent_s']:.2f} s late")
    if g["stream"] == "commands" and g["missing"]:
        what += ", input unknown there (the filter forgot the motion, kept m and Izz)"
    return (f"{g['stream']}: gap {g['t_start'] - t0:.2f}-{g['t_end'] - t0:.2f} s "
            f"({g['duration_s']:.2f} s), {what}")


SUMMARY_GAPS = 100
"""Gaps listed in the summary (``gaps``); gaps.csv holds them all."""


def gap_warnings(rows: list[dict[str, Any]], t0: float | None = None, n_long: int = 10
                 ) -> list[str]:
    """The warning lines for ``rows`` (:meth:`GapTracker.rows`): each long gap (0.1 s and
    more, or 5 messages missing, or a pause) on its own line, at most ``n_long``, the rest
    (a replayed run's dropped frames, a lossy camera link) counted in one line per stream."""
    def long(g: dict[str, Any]) -> bool:
        return g["duration_s"] >= 0.1 or g["missing"] >= 5 or g["missing"] == 0

    lines = [gap_sentence(g, t0) for g in rows if long(g)][:n_long]
    n_more = sum(1 for g in rows if long(g)) - len(lines)
    for stream in ("poses", "commands"):
        short = [g for g in rows if g["stream"] == stream and not long(g)]
        if short:
            lines.append(f"{stream}: {len(short)} short gaps (under 0.1 s, "
                         f"{sum(g['missing'] for g in short)} missing in all; gaps.csv lists each)")
    if n_more > 0:
        lines.append(f"{n_more} more gaps (gaps.csv lists each)")
    return lines


class GapTracker:
    """Watch the pose and command streams of one body for gaps (see the module notes).

    Args:
        silence_s: host seconds without a message named a gap though nothing is missing.
        csv_path: where to append each gap as found (``gaps.csv``; None: nowhere).
    """

    def __init__(self, silence_s: float = DEFAULT_SILENCE_S, csv_path: str | Path | None = None
                 ) -> None:
        self.silence_s = float(silence_s)
        self.gaps: list[Gap] = []
        self.csv_path = None if csv_path is None else Path(csv_path)
        self._pose: tuple[int, float, float] | None = None  # frame, t, arrival
        self._cmd: dict[str, tuple[int, float, float]] = {}  # per body: seq, t, arrival
        self._unknown: list[tuple[float, float]] = []
        self._resume: dict[str, tuple[float, float]] = {}

    # ------------------------------------------------------------------ input
    def pose(self, frame: int, t: float, arrival: float) -> Gap | None:
        """A pose received (occluded ones too); the gap it ends, if any."""
        last = self._pose
        if last is None and "poses" in self._resume:
            return self._after_resume("poses", frame, t, arrival)
        if last is not None and frame <= last[0]:
            if frame < last[0] - 1_000_000:  # the mocap restarted its count: start again
                self._pose = (frame, t, arrival)
            return None
        self._pose = (frame, t, arrival)
        if last is None:
            return None
        missing = frame - last[0] - 1
        silent = arrival - last[2]
        if missing > 0 or silent > self.silence_s:
            return self._add(Gap("poses", last[1], t, missing, silent, last[0], frame, arrival))
        return None

    def command(self, body: str, seq: int | None, t: float, arrival: float) -> Gap | None:
        """A command message received (``seq``: its number); the gap it ends, if any. A gap
        with commands missing is also an interval of unknown input."""
        if not isinstance(seq, int):
            return None
        last = self._cmd.get(body)
        if last is None and "commands" in self._resume:
            self._cmd[body] = (seq, t, arrival)
            return self._after_resume("commands", seq, t, arrival)
        if last is not None and seq <= last[0]:
            return None
        self._cmd[body] = (seq, t, arrival)
        if last is None:
            return None
        missing = seq - last[0] - 1
        silent = arrival - last[2]
        if missing > 0 or silent > self.silence_s:
            g = self._add(Gap("commands", last[1], t, missing, silent, last[0], seq, arrival))
            if missing > 0:
                self._unknown.append((last[1], t))
            return g
        return None

    def resumed(self, t_pose: float | None, pose_period_s: float, t_cmd: float | None,
                cmd_period_s: float) -> None:
        """The streams continue a dead run whose last pose and command were at ``t_pose``
        and ``t_cmd`` (lab s): the first of each that arrives ends a gap, its ``missing``
        estimated from the recorded periods (s); the commands' is unknown input."""
        if t_pose is not None:
            self._resume["poses"] = (t_pose, pose_period_s)
        if t_cmd is not None:
            self._resume["commands"] = (t_cmd, cmd_period_s)

    def _after_resume(self, stream: str, number: int, t: float, arrival: float) -> Gap | None:
        t_prev, period = self._resume.pop(stream)
        if stream == "poses":
            self._pose = (number, t, arrival)
        if t <= t_prev:
            return None
        missing = max(1, round((t - t_prev) / max(period, 1e-6)) - 1)
        g = self._add(Gap(stream, t_prev, t, missing, t - t_prev, 0, number, arrival))
        if stream == "commands":
            self._unknown.append((t_prev, t))
        return g

    # ------------------------------------------------------------------ queries
    def input_unknown(self, t0: float, t1: float) -> bool:
        """Whether the valves' input is unknown somewhere in ``(t0, t1)`` (lab s)."""
        for a, b in reversed(self._unknown):
            if a < t1 and b > t0:
                return True
            if b <= t0 and len(self._unknown) > 8:
                break
        return False

    def rows(self, limit: int | None = None) -> list[dict[str, Any]]:
        """The gaps as dicts (the first ``limit``; None: all)."""
        return [g.as_dict() for g in self.gaps[:limit]]

    def summary(self) -> dict[str, Any]:
        """``gaps`` (the first :data:`SUMMARY_GAPS`), ``gap_count``, ``poses_missing``,
        ``commands_missing``: the summary's part."""
        return {"gaps": self.rows(SUMMARY_GAPS), "gap_count": len(self.gaps),
                "poses_missing": self.missing("poses"),
                "commands_missing": self.missing("commands")}

    def missing(self, stream: str) -> int:
        return sum(g.missing for g in self.gaps if g.stream == stream)

    # ------------------------------------------------------------------ output
    def _add(self, g: Gap) -> Gap:
        self.gaps.append(g)
        if self.csv_path is not None:
            try:
                new = not self.csv_path.exists()
                with self.csv_path.open("a") as fh:
                    if new:
                        fh.write(",".join(GAP_COLUMNS) + "\n")
                    fh.write(f"{g.stream},{g.t_start:.9f},{g.t_end:.9f},{g.duration_s:.6f},"
                             f"{g.missing},{g.silent_s:.6f},{g.before},{g.after},{g.host_end:.6f}\n")
            except OSError:  # the run folder is the recorder's to report; the gap stays named
                pass
        return g


def forget_motion(P, P0, dt_s: float, acc_max: float, alpha_max: float) -> None:
    """In place: the motion states' block of the covariance ``P`` (x, y, psi, u, v, r: the
    first six) reset and uncorrelated with the parameters, for an interval of ``dt_s``
    seconds whose input is unknown: each motion state's sigma becomes the larger of the
    start's (``P0``) and what full thrust could have changed over the interval
    (``acc_max`` m/s^2, ``alpha_max`` rad/s^2; yaw at most pi). What the filter knew of
    the motion is gone, what it knew of the parameters stays, and the poses after the
    interval start the motion afresh."""
    n = 6
    dt = max(float(dt_s), 0.0)
    grow = (0.5 * acc_max * dt * dt, 0.5 * acc_max * dt * dt,
            min(0.5 * alpha_max * dt * dt, math.pi), acc_max * dt, acc_max * dt, alpha_max * dt)
    sig = [max(math.sqrt(max(float(P0[i, i]), 0.0)), g) for i, g in enumerate(grow)]
    if not all(math.isfinite(s) for s in sig):
        return
    P[:n, :] = 0.0
    P[:, :n] = 0.0
    for i, s in enumerate(sig):
        P[i, i] = s * s
