"""The offset between the mocap host's clock and the player's, measured from the streams
(pure logic; no network code).

Poses are stamped on the mocap host, commands on the player's host, and both arrive at
the estimator's host, whose clock stamps their arrival. For each stream, ``arrival -
stamp`` is the one-way delay plus the difference of the two clocks; its *lower envelope*
(the least-delayed messages) is the network's minimum delay plus that difference. So

    offset = mocap clock - player clock ~= min(arrival - t_cmd) - min(arrival - t_pose)

to within the difference of the two paths' minimum delays (a fraction of a millisecond on
a LAN; it cannot be told apart from an offset without a round trip). :class:`OffsetMeter`
takes the minimum of each stream in windows of ``window_s`` host seconds; each window
with both streams gives one estimate; the result is their median and, as its sigma, their
spread (1.4826 MAD) over the square root of their number. A 20 ms offset looks exactly
like a 20 ms valve dead time to the estimators: this is what measures it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

DEFAULT_WINDOW_S = 1.0


@dataclass(frozen=True)
class OffsetEstimate:
    """The measured offset (s, mocap clock minus the player's), its sigma (s), and the
    number of windows it rests on."""

    offset_s: float
    sigma_s: float
    windows: int

    def as_dict(self) -> dict[str, float | int]:
        return {"clock_offset_ms": 1e3 * self.offset_s, "clock_offset_sigma_ms": 1e3 * self.sigma_s,
                "clock_offset_windows": self.windows}


class OffsetMeter:
    """Lower envelopes of the pose and command delays, per window (see the module notes)."""

    def __init__(self, window_s: float = DEFAULT_WINDOW_S) -> None:
        self.window_s = float(window_s)
        self._win: int | None = None
        self._min_pose = math.inf
        self._min_cmd = math.inf
        self.samples: list[float] = []
        """One offset (s) per closed window that had both streams."""

    def _roll(self, arrival: float) -> None:
        w = math.floor(arrival / self.window_s)
        if self._win is None:
            self._win = w
        elif w != self._win:
            if math.isfinite(self._min_pose) and math.isfinite(self._min_cmd):
                self.samples.append(self._min_cmd - self._min_pose)
            self._win, self._min_pose, self._min_cmd = w, math.inf, math.inf

    def pose(self, t: float, arrival: float) -> None:
        """A pose stamped ``t`` (mocap clock, s) that arrived at ``arrival`` (this host)."""
        self._roll(arrival)
        self._min_pose = min(self._min_pose, arrival - t)

    def command(self, t: float, arrival: float) -> None:
        """A command stamped ``t`` (player clock, s) that arrived at ``arrival``."""
        self._roll(arrival)
        self._min_cmd = min(self._min_cmd, arrival - t)

    def estimate(self) -> OffsetEstimate | None:
        """The offset so far (None before two windows with both streams)."""
        s = sorted(self.samples)
        n = len(s)
        if n < 2:
            return None
        med = s[n // 2] if n % 2 else 0.5 * (s[n // 2 - 1] + s[n // 2])
        dev = sorted(abs(x - med) for x in s)
        mad = dev[n // 2] if n % 2 else 0.5 * (dev[n // 2 - 1] + dev[n // 2])
        return OffsetEstimate(med, 1.4826 * mad / math.sqrt(n), n)
