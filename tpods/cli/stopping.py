"""How the long-running commands stop, the same way in each.

- The Zenoh commands (``mocap bridge|record``, ``replay``, ``view``, ``estimate live``)
  run in :func:`zenoh_session`: their session, open while SIGTERM and Ctrl-C set a
  ``stop`` event (:func:`stop_on_signals`) so every exit path closes it cleanly;
  :func:`wait_for_stop` is their wait until the event, ``--duration`` or neither.
- The valve commands (``bench characterize``, ``run play``) let SIGTERM and Ctrl-C raise
  (the valves close in ``finally``) and end with :func:`valves_closed_exit`: one stderr
  line and the exit status 143 or 130.
"""

from __future__ import annotations

import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any


@contextmanager
def stop_on_signals(stop: threading.Event) -> Iterator[None]:
    """SIGTERM (and SIGINT) set ``stop`` so every exit path closes cleanly."""
    old = {}
    for sig in (signal.SIGTERM, signal.SIGINT):
        try:
            old[sig] = signal.signal(sig, lambda *_a: stop.set())
        except ValueError:  # not the main thread
            pass
    try:
        yield
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)


@contextmanager
def zenoh_session(args: Any, stop: threading.Event) -> Iterator[Any]:
    """The Zenoh session of the command's options (:func:`common.zenoh_net.open_session`),
    with SIGTERM and SIGINT setting ``stop`` while it is open; closed on every exit path."""
    from common.zenoh_net import open_session  # lazy: the session loads zenoh

    with stop_on_signals(stop):
        session = open_session(args)
        try:
            yield session
        finally:
            session.close()


def wait_for_stop(stop: threading.Event, duration_s: float | None, tick: Callable[[], None],
                  every_s: float = 1.0) -> None:
    """Wait until ``stop`` is set or ``duration_s`` has passed (None: no limit), calling
    ``tick`` (the console line) every ``every_s`` seconds."""
    t_end = None if duration_s is None else time.monotonic() + duration_s
    while not stop.is_set():
        wait = every_s if t_end is None else min(every_s, t_end - time.monotonic())
        if wait <= 0:
            break
        stop.wait(wait)
        tick()


def valves_closed_exit(exc: BaseException, note: str) -> int:
    """How a valve command ends on SIGTERM (:class:`bench.session.Terminated`: 143) or
    Ctrl-C (KeyboardInterrupt: 130): ``tpods: terminated; NOTE`` on stderr, and the status."""
    from bench.session import Terminated

    terminated = isinstance(exc, Terminated)
    print(f"tpods: {'terminated' if terminated else 'interrupted'}; {note}", file=sys.stderr)
    return 143 if terminated else 130
