"""Calls queued in a caller's process and handed in batches to a writer process over a pipe.

The writers of a live estimator's recordings (:mod:`common.mcap.process`,
:mod:`estimator.live.recorder_process`) run in processes of their own; the estimator's
thread only appends to a deque (atomic, no lock). A feeder thread sends the queue as one
``("batch", items, monotonic time)`` message every ``every_s``, woken early by
:meth:`BatchFeeder.idle` when the caller's loop has nothing to do (so that pickling and a
full pipe never hold the caller), or else once the queue is one and a half periods old.
:meth:`BatchFeeder.finish` hands over what is left, sends ``("close", status, extra)`` and
waits for the writer's reply, killing it if it does not end.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from typing import Any

CLOSE_TIMEOUT_S = 60.0


class BatchFeeder:
    """The caller's side of a writer process (module doc).

    Args:
        conn: the caller's end of the pipe. proc: the writer process. name: the feeder
            thread's name. every_s: the hand-over period, s.
    """

    def __init__(self, conn: Any, proc: Any, name: str, every_s: float) -> None:
        self.conn = conn
        self.proc = proc
        self.every_s = every_s
        self.queue: deque = deque()
        self.lost = 0
        """Items that could not be handed over (the writer had died)."""
        self.dead = False
        self.lock = threading.Lock()  # one sender on the pipe at a time
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._last_feed = time.monotonic()
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)
        self._thread.start()

    def send_locked(self) -> None:
        """Hand the queue over now (the caller holds :attr:`lock`)."""
        self._last_feed = time.monotonic()
        items = []
        while self.queue:
            items.append(self.queue.popleft())
        if not items:
            return
        if self.dead:
            self.lost += len(items)
            return
        try:
            self.conn.send(("batch", items, time.monotonic()))
        except (OSError, ValueError):  # the writer is gone: counted, said at close
            self.dead = True
            self.lost += len(items)

    def idle(self) -> None:
        """The caller's loop is idle: wake the feeder thread if the last hand-over is a
        period old (it pickles and writes; the caller never waits for the pipe)."""
        if time.monotonic() - self._last_feed >= self.every_s and self.queue:
            self._wake.set()

    def ask(self, message: tuple, timeout_s: float = CLOSE_TIMEOUT_S) -> Any:
        """Hand the queue over, send ``message`` and return the writer's reply (None: no
        reply within ``timeout_s`` or the writer is gone)."""
        with self.lock:
            self.send_locked()
            if self.dead:
                return None
            try:
                self.conn.send(message)
                return self.conn.recv() if self.conn.poll(timeout_s) else None
            except (OSError, EOFError):
                self.dead = True
                return None

    def _loop(self) -> None:
        while not self._stop.is_set():
            woke = self._wake.wait(self.every_s)
            self._wake.clear()
            if self._stop.is_set():
                break
            if woke or time.monotonic() - self._last_feed >= 1.5 * self.every_s:
                with self.lock:
                    self.send_locked()

    def finish(self, status: str, extra: dict[str, Any] | None = None) -> Any:
        """Stop the feeder, hand over what is left, ask the writer to close with ``status``
        and ``extra``, and wait for its reply (None: none came); the process is joined,
        killed if it does not end."""
        self._stop.set()
        self._wake.set()
        self._thread.join(timeout=5.0)
        reply = self.ask(("close", status, extra or {}))
        with self.lock:
            self.conn.close()
        self.proc.join(CLOSE_TIMEOUT_S)
        if self.proc.is_alive():
            self.proc.kill()
            self.proc.join(5.0)
        return reply
