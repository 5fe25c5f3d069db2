"""Serve a byte-stream device emulator on a pseudo-terminal.

An emulator is any object with

- ``receive(data: bytes, now: float) -> bytes``: bytes written by the host; returns
  the reply bytes (possibly empty);
- ``tick(now: float) -> tuple[bytes, float | None]``: unsolicited output due at
  ``now`` (continuous print, watchdog) and the monotonic time of the next tick
  (None: nothing scheduled).

:func:`serve_pty` opens a pty pair, puts the slave in raw mode (no echo, no CR/LF
translation) and runs a thread that moves bytes between the master side and the
emulator. The slave device path (``/dev/pts/N``) is what pyserial opens. The server
keeps its own slave descriptor open, so the client may close, crash or be killed and
reconnect; output nobody reads is dropped once the pty buffer is full.

A pty moves bytes instantly whatever baud rate the client sets. ``baud`` paces both
directions like a serial line (``bits_per_byte`` per byte, 10 for 8N1): the emulator
gets the host's bytes once they would have crossed the line, and its replies appear
once their last byte would have arrived.
"""

from __future__ import annotations

import errno
import os
import select
import threading
import time
import tty
from collections import deque
from typing import Protocol, Self


class Emulator(Protocol):
    def receive(self, data: bytes, now: float) -> bytes: ...

    def tick(self, now: float) -> tuple[bytes, float | None]: ...


class EmulatorServer:
    """What the pty and TCP servers share: a thread that runs ``_loop`` until
    :meth:`stop`, which wakes it, waits for it and releases the device; a context manager."""

    _stop: threading.Event
    _thread: threading.Thread

    def _start(self, name: str) -> None:
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)
        self._thread.start()

    def _loop(self) -> None:
        raise NotImplementedError

    def _wake(self) -> None:
        """Interrupt the loop's wait (default: it wakes by itself within its idle time)."""

    def _release(self) -> None:
        raise NotImplementedError

    def stop(self) -> None:
        """Stop the thread and release the device (idempotent)."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._wake()
        self._thread.join(timeout=2.0)
        self._release()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


class PtyServer(EmulatorServer):
    """A running pty server: ``path`` is the device to open; ``stop()`` ends it."""

    def __init__(self, emulator: Emulator, max_idle_s: float = 0.02, baud: float | None = None,
                 bits_per_byte: int = 10) -> None:
        self.emulator = emulator
        self._max_idle_s = max_idle_s
        self.baud = baud
        self._byte_s = bits_per_byte / baud if baud else 0.0
        self._rx: deque[tuple[float, bytes]] = deque()  # (time the last byte is in, bytes)
        self._tx: deque[tuple[float, bytes]] = deque()
        self._rx_free = self._tx_free = 0.0
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self.path: str = os.ttyname(self._slave)
        self.dropped_bytes = 0
        self._wake_r, self._wake_w = os.pipe()
        self._start(f"pty-{self.path}")

    # ---------------------------------------------------------------- loop
    def _write(self, data: bytes) -> None:
        while data:
            try:
                n = os.write(self._master, data)
            except BlockingIOError:  # nobody reads: drop, like a UART with no listener
                self.dropped_bytes += len(data)
                return
            except OSError:
                return
            data = data[n:]

    def _out(self, data: bytes) -> None:
        if not data:
            return
        if not self._byte_s:
            self._write(data)
            return
        self._tx_free = max(time.monotonic(), self._tx_free) + len(data) * self._byte_s
        self._tx.append((self._tx_free, data))

    def _loop(self) -> None:
        next_tick: float | None = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            while self._rx and self._rx[0][0] <= now:
                self._out(self.emulator.receive(self._rx.popleft()[1], now))
                next_tick = now  # a command may change the schedule
            if next_tick is not None and now >= next_tick:
                out, next_tick = self.emulator.tick(now)
                self._out(out)
                now = time.monotonic()
            while self._tx and self._tx[0][0] <= now:
                self._write(self._tx.popleft()[1])
            due = [t for t in (next_tick, self._rx[0][0] if self._rx else None,
                               self._tx[0][0] if self._tx else None) if t is not None]
            wait = self._max_idle_s if not due else min(self._max_idle_s, max(0.0, min(due) - now))
            try:
                ready, _, _ = select.select([self._master, self._wake_r], [], [], wait)
            except (OSError, ValueError):
                return
            if self._master in ready:
                try:
                    data = os.read(self._master, 4096)
                except BlockingIOError:
                    continue
                except OSError as exc:  # EIO: no slave open (cannot happen: we hold one)
                    if exc.errno == errno.EIO:
                        time.sleep(0.01)
                        continue
                    return
                if data and self._byte_s:
                    self._rx_free = max(time.monotonic(), self._rx_free) + len(data) * self._byte_s
                    self._rx.append((self._rx_free, data))
                elif data:
                    self._out(self.emulator.receive(data, time.monotonic()))
                # a command may change the schedule (continuous print started)
                next_tick = time.monotonic()

    # ------------------------------------------------------------- control
    def _wake(self) -> None:
        os.write(self._wake_w, b"x")

    def _release(self) -> None:
        """Close the pty."""
        for fd in (self._master, self._slave, self._wake_r, self._wake_w):
            try:
                os.close(fd)
            except OSError:
                pass


def serve_pty(emulator: Emulator, baud: float | None = None) -> PtyServer:
    """Serve ``emulator`` on a new pty; returns the server (``.path``, ``.stop()``).

    ``baud``: pace the bytes like a serial line at this rate (None: as fast as the pty)."""
    return PtyServer(emulator, baud=baud)
