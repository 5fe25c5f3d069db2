"""Flights fly one at a time, and the background lane waits while one flies.

A *flight* (a test marked ``flight``: the demo, the structure and vehicle demos, e2e, the
plant on a vehicle) runs the simulated plant, the player and the live estimator as
processes on the lab clock and is judged by how late the emulated valves switched.

Why the background lane must pause (measured 2026-11-27 on the 2-core CI machine,
kernel 6.18, ``sched_autogroup_enabled=1``): with the low-priority background worker of
tests/support/lanes.py filling every idle moment, kernel threads were starved for up to
1.5 s (``perf sched``: an unbound kworker and ``ksoftirqd/0`` woken and not run for
1.44 s and 1.58 s while the nice-10 worker and the flight's threads ran). A pty moves its
bytes in such a kworker, so the emulated valve controller's reads blocked (state D) and
the player's commands went unanswered for a second. A pty round-trip probe beside
``make test`` saw 10 round trips over 30 ms (worst 287 ms) and three flights skipped as
too loaded; with two workers and no background lane, 0 and 0; with autogroups off
(every task in the root group), 0 and 0; with three equal workers (no nice), 14 (worst
1076 ms) and a failed demo. So the starvation comes with group scheduling (autogroups) on a
machine that never idles, not from the flights' own load; the mechanism inside the
scheduler was not traced further.

The locks are ``flock`` locks on two files in the run's shared temporary folder:

- ``tpods-flight.lock``: a flight holds it exclusively for its whole run; the background
  worker takes it shared for a moment before each test, so it cannot start a test while
  a flight flies;
- ``tpods-flight-gate.lock``: the background worker holds it shared for the whole of each
  test; a flight takes it exclusively, so it waits for the background test under way to
  end before it starts.

Without ``fcntl`` (not POSIX) both are no-ops.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path

try:
    import fcntl
except ImportError:  # pragma: no cover (not POSIX)
    fcntl = None

FLIGHT_LOCK = "tpods-flight.lock"
GATE_LOCK = "tpods-flight-gate.lock"


@contextlib.contextmanager
def _locked(path: Path, how: int) -> Iterator[None]:
    with open(path, "a") as fh:
        fcntl.flock(fh, how)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


@contextlib.contextmanager
def flight(folder: Path) -> Iterator[None]:
    """Hold the machine for one flight: no other flight, no background test."""
    if fcntl is None:  # pragma: no cover
        yield
        return
    with _locked(folder / FLIGHT_LOCK, fcntl.LOCK_EX), _locked(folder / GATE_LOCK, fcntl.LOCK_EX):
        yield


@contextlib.contextmanager
def background_test(folder: Path) -> Iterator[None]:
    """Run one background-lane test: wait while a flight flies, then keep flights out."""
    if fcntl is None:  # pragma: no cover
        yield
        return
    with open(folder / FLIGHT_LOCK, "a") as wait_fh, open(folder / GATE_LOCK, "a") as gate_fh:
        fcntl.flock(wait_fh, fcntl.LOCK_SH)  # blocks while a flight holds it
        try:
            fcntl.flock(gate_fh, fcntl.LOCK_SH)
        finally:
            fcntl.flock(wait_fh, fcntl.LOCK_UN)
        try:
            yield
        finally:
            fcntl.flock(gate_fh, fcntl.LOCK_UN)
