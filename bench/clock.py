"""The bench's clock: ``monotonic()`` and ``sleep()`` used by the serial link, the drivers
and the characterisation session.

Normally the system's monotonic clock. A strict replay of serial transcripts
(:mod:`bench.protocol_replay`) installs a virtual clock while its ports are open: time
then advances only as the recording says (a read that times out moves it by the
timeout, a recorded reply sets it to the time it was read), so a replayed session sees
the same times as the recorded one, bit for bit, and runs as fast as the host computes.
Threads other than the one that replays (the valve watchdog feeder) see the same clock.
"""

from __future__ import annotations

import threading
import time
from typing import Protocol


class Clock(Protocol):
    def monotonic(self) -> float: ...
    def sleep(self, seconds: float) -> None: ...


_lock = threading.Lock()
_installed: Clock | None = None
_users = 0

monotonic = time.monotonic
"""Seconds, monotonic (rebound to the virtual clock while one is installed)."""
sleep = time.sleep
"""Wait ``seconds`` (virtual: advance the clock)."""


def install(clock: Clock) -> Clock:
    """Use ``clock`` until :func:`release`; a second install while one is in use shares
    the installed clock (two replayed ports, one time line). Returns the clock in use."""
    global _installed, _users, monotonic, sleep
    with _lock:
        if _installed is None:
            _installed = clock
            monotonic = clock.monotonic
            sleep = clock.sleep
        _users += 1
        return _installed


def release() -> None:
    """One user of the installed clock is done; the last one restores the system clock."""
    global _installed, _users, monotonic, sleep
    with _lock:
        _users = max(0, _users - 1)
        if _users == 0:
            _installed = None
            monotonic = time.monotonic
            sleep = time.sleep


def installed() -> Clock | None:
    return _installed
