"""A measured clock offset applied during the run (pure logic; no network code).

:class:`~estimator.live.clock_offset.OffsetMeter` measures the mocap host's clock minus
the player's from the streams. :class:`OffsetApplier` decides, once, when that measurement
has settled: at least ``min_windows`` windows, an offset clearly there (above
``min_offset_s`` and ``k_sigma`` sigmas), a sigma small against it (at most
``rel_sigma`` of it), and windows that agree (their spread, sigma times the square root of
their number, at most ``max_spread_s``: the lower envelopes of a LAN agree to a fraction of
a millisecond; streams stamped on a scaled lab clock drift within every window and do not). From then on every pose *arriving* is taken onto the player's clock
by the offset too (the same path as a given offset); the poses already taken keep their
times, so the filter is never re-run. A pose whose corrected time falls at or before the
last pose taken before the change (the clocks' overlap, an offset of 20 ms at 100 Hz: two
poses) is counted and skipped. A second meter, fed the corrected times, measures the
offset left after the change (the residual).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from estimator.live.clock_offset import OffsetEstimate, OffsetMeter

MIN_WINDOWS = 5
"""Windows (of 1 s) the measurement must rest on before it is applied."""

MIN_OFFSET_S = 1e-3
"""An offset below this (s) is not applied: the paths' delay asymmetry is of that size."""


@dataclass
class OffsetApplier:
    """The measured offset applied once it has settled (see the module notes)."""

    enabled: bool = True
    min_windows: int = MIN_WINDOWS
    min_offset_s: float = MIN_OFFSET_S
    k_sigma: float = 5.0
    rel_sigma: float = 0.1
    max_spread_s: float = 2e-3
    applied_s: float = 0.0
    """The offset applied (s, mocap clock minus the player's); 0 before the change."""
    at_t_s: float | None = None
    """Pose time (player clock, s) of the first pose taken with the offset applied."""
    at_arrival_s: float | None = None
    """Host time (s) at which it was applied."""
    basis: OffsetEstimate | None = None
    """The measurement it was applied from."""
    floor_t_s: float = -math.inf
    """The latest pose time taken before the change (s)."""
    skipped: int = 0
    """Poses skipped in the clocks' overlap."""
    residual: OffsetMeter = field(default_factory=OffsetMeter)
    just_applied: bool = False
    """True from the change until :meth:`take_news` is called (one message)."""

    def settled(self, est: OffsetEstimate | None) -> bool:
        """Whether ``est`` is fit to apply (enough windows, clearly there, sigma small)."""
        if est is None or est.windows < self.min_windows:
            return False
        off = abs(est.offset_s)
        return (off >= self.min_offset_s and off >= self.k_sigma * est.sigma_s
                and est.sigma_s <= self.rel_sigma * off
                and est.sigma_s * math.sqrt(est.windows) <= self.max_spread_s)

    def consider(self, est: OffsetEstimate | None, arrival: float) -> None:
        """Apply ``est`` if not yet applied, enabled and settled."""
        if not self.enabled or self.at_arrival_s is not None or not self.settled(est):
            return
        assert est is not None
        self.applied_s, self.at_arrival_s, self.basis = est.offset_s, arrival, est
        self.just_applied = True

    def pose_time(self, t: float, arrival: float) -> tuple[float, bool]:
        """A pose time (s, on the player's clock but for the measured offset) corrected by
        the applied offset, and whether it falls in the clocks' overlap (then skipped)."""
        if self.at_arrival_s is None:
            self.floor_t_s = max(self.floor_t_s, t)
            return t, False
        tc = t - self.applied_s
        if tc <= self.floor_t_s:
            self.skipped += 1
            return tc, True
        if self.at_t_s is None:
            self.at_t_s = tc
        self.residual.pose(tc, arrival)
        return tc, False

    def command(self, t: float, arrival: float) -> None:
        """A command (player clock) for the residual meter."""
        if self.at_arrival_s is not None:
            self.residual.command(t, arrival)

    def take_news(self) -> bool:
        """True once, right after the change (for a one-time message)."""
        news, self.just_applied = self.just_applied, False
        return news

    def as_dict(self) -> dict[str, object]:
        """The change for the summary and run.json (ms, s, counts)."""
        if self.at_arrival_s is None or self.basis is None:
            return {"clock_offset_applied": None, "clock_offset_auto": self.enabled}
        r = self.residual.estimate()
        return {"clock_offset_auto": self.enabled, "clock_offset_applied": {
            "offset_ms": 1e3 * self.applied_s, "sigma_ms": 1e3 * self.basis.sigma_s,
            "windows": self.basis.windows, "from_pose_t_s": self.at_t_s,
            "at_host_t_s": self.at_arrival_s, "poses_skipped_in_overlap": self.skipped,
            "residual_ms": None if r is None else 1e3 * r.offset_s,
            "residual_sigma_ms": None if r is None else 1e3 * r.sigma_s,
            "residual_windows": 0 if r is None else r.windows}}

    def message(self) -> str:
        """One line saying what was applied, when, from how many windows."""
        b = self.basis
        assert b is not None and self.at_arrival_s is not None
        return (f"live: clock offset {1e3 * b.offset_s:+.2f} +/- {1e3 * b.sigma_s:.2f} ms "
                f"(mocap host minus player host, {b.windows} windows of 1 s) applied to every "
                "pose from now on (--clock-offset-ms none: never)")
