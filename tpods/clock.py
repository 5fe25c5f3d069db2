"""The lab clock: host time, optionally running faster than real time.

Every live message (commands, poses, estimates) carries ``t`` on the *lab clock*. At
``scale`` 1 the lab clock is the host clock (``time.time()``, seconds since the
epoch), so processes on one host (or on hosts synchronised by NTP/PTP) agree. With a
simulated plant the player and the plant may run ``scale`` times faster than real
time: the lab clock then reads ``origin + scale * (time.time() - origin)``. Two
processes given the same ``scale`` and ``origin`` read the same lab time, so the
commands of a player and the poses of a simulated plant stay consistent at any speed.
Real valves and a real mocap always run at scale 1.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field

from common.errors import UserError


@dataclass
class LabClock:
    """Lab time in seconds (epoch-based), ``scale`` times faster than the host clock.

    Args:
        scale: lab seconds per real second (1 = real time).
        origin: host time (``time.time()``) at which lab and host clocks coincide
            (default: now). Give the same origin to every process of one run.
    """

    scale: float = 1.0
    origin: float = field(default_factory=time.time)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.scale) and self.scale > 0):
            raise UserError(f"time scale must be a positive number, got {self.scale:g}")
        if not math.isfinite(self.origin):
            raise UserError("clock origin must be finite")

    def now(self) -> float:
        """Lab time now, s."""
        if self.scale == 1.0:
            return time.time()
        return self.origin + self.scale * (time.time() - self.origin)

    __call__ = now

    def to_lab(self, host_t: float) -> float:
        """Lab time of a host time (``time.time()`` scale), s."""
        return self.origin + self.scale * (host_t - self.origin)

    def to_host(self, lab_t: float) -> float:
        """Host time at which the lab clock reads ``lab_t``, s."""
        return self.origin + (lab_t - self.origin) / self.scale

    def real_s(self, lab_s: float) -> float:
        """Real seconds for a lab duration."""
        return lab_s / self.scale

    def sleep_until(self, lab_t: float, stop: threading.Event | None = None,
                    max_chunk_s: float = 0.05) -> bool:
        """Sleep until the lab clock reads ``lab_t``; False if ``stop`` was set first.

        Sleeps in chunks of at most ``max_chunk_s`` real seconds (so a caller can be
        interrupted by a signal or ``stop``), then spins for the last 0.3 ms.
        """
        while True:
            wait = (lab_t - self.now()) / self.scale
            if wait <= 0:
                return True
            if stop is not None and stop.is_set():
                return False
            if wait > 3e-4:
                chunk = min(wait - 2e-4, max_chunk_s)
                if stop is not None:
                    if stop.wait(chunk):
                        return False
                else:
                    time.sleep(chunk)
