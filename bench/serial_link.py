"""Line-oriented serial link shared by the bench drivers.

Opens any pyserial URL (``/dev/ttyACM0``, ``socket://HOST:PORT``, ``loop://``, a pty
path) with :func:`serial.serial_for_url`, or wraps an already open port-like object
(anything with ``write``, ``read`` and ``in_waiting``: tests pass scripted fakes).
Reads lines against a deadline, so a caller can wait until a given time without
treating the wait as a silent device.

``capture=PATH`` records every chunk written and read, byte-exact with its time, as a
serial transcript (:mod:`bench.capture`, docs/recordings.md); ``replay://PATH`` opens
such a transcript as a device (:mod:`bench.protocol_replay`). ``line_t`` is the host
time at which the bytes completing the last line returned were read.

:class:`SerialDevice` is the drivers' common lifecycle: ``with Driver(url) as d`` opens the
link and closes it on every exit path.
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any, Self

import serial

from bench import clock
from bench.capture import Transcript
from common.errors import DeviceError

if "bench" not in serial.protocol_handler_packages:  # replay://PATH (bench.protocol_replay)
    serial.protocol_handler_packages.append("bench")

_EOL = re.compile(rb"[\r\n]")
MAX_LINE = 512


try:  # a pty or tty whose other end has gone fails in tcdrain with termios.error (EIO)
    import termios

    IO_ERRORS: tuple[type[BaseException], ...] = (OSError, termios.error)
except ImportError:  # pragma: no cover - not POSIX
    IO_ERRORS = (OSError,)
"""What a serial port raises when the device or its link is gone."""


class SerialLink:
    """A byte link with a line reader.

    Args:
        port: pyserial URL or an open port-like object.
        name: what the device is, for error messages ("valve controller").
        poll_s: read timeout of one poll, seconds (granularity of deadlines).
        capture: write a serial transcript of this link to this file (None: no capture).
        keepalive: a command the driver sends from a thread at scheduler-decided times
            (named in the transcript's header, for strict replays).
        **settings: pyserial settings (baudrate, bytesize, parity, stopbits, ...).
    """

    def __init__(self, port: str | Any, name: str, poll_s: float = 0.02, *,
                 capture: str | Path | None = None, keepalive: bytes | None = None,
                 **settings: Any) -> None:
        self.name = name
        self.poll_s = poll_s
        self._timeout = poll_s
        self._buf = b""
        self.line_t = math.nan
        """Host time of the last read that returned bytes (the line just returned was completed then)."""
        self.tx_t = math.nan
        """Host time at which the last write returned."""
        self.capture: Transcript | None = None
        if isinstance(port, str):
            self.url = port
            try:
                self.port = serial.serial_for_url(port, timeout=poll_s, write_timeout=2.0, **settings)
            except (serial.SerialException, OSError, ValueError) as exc:
                reason = str(exc).split("\n")[0] or exc.__class__.__name__
                raise DeviceError(f"cannot open the {name} at {port!r}: {reason}") from None
        else:
            self.url = getattr(port, "name", None) or repr(port)
            self.port = port
        if capture is not None:
            try:
                self.capture = Transcript(capture, device=name, url=str(self.url), settings=settings,
                                          t_open=clock.monotonic(), poll_s=poll_s, keepalive=keepalive)
            except BaseException:
                self.close()
                raise

    def write(self, data: bytes) -> None:
        try:
            self.port.write(data)
            flush = getattr(self.port, "flush", None)
            if flush is not None:
                flush()
        except IO_ERRORS as exc:  # serial.SerialException is an OSError
            raise DeviceError(f"{self.name} at {self.url}: write failed ({exc})") from None
        self.tx_t = t = clock.monotonic()
        if self.capture is not None:
            self.capture.chunk(t, "tx", data)

    def pull(self) -> None:
        """Move every byte already received by the OS into the line buffer (never waits)."""
        try:
            n = int(self.port.in_waiting or 0)
            if n:
                chunk = self.port.read(n)
                if chunk:
                    self._got(chunk, True)
        except IO_ERRORS as exc:
            raise DeviceError(f"{self.name} at {self.url}: read failed ({exc})") from None

    def reset_input(self) -> None:
        """Drop unread bytes (stale replies, continuous prints)."""
        self._buf = b""
        reset = getattr(self.port, "reset_input_buffer", None)
        if reset is not None:
            try:
                reset()
            except IO_ERRORS:
                pass

    @property
    def pending(self) -> bytes:
        """Bytes received after the last complete line (a line still without its terminator)."""
        return self._buf

    def readline(self, deadline: float) -> bytes | None:
        """Next non-empty line without its terminator, or None once ``deadline`` (monotonic) passes.

        A run of more than MAX_LINE bytes without a terminator is returned as one line
        (the caller's parser rejects it as garbage).
        """
        while True:
            m = _EOL.search(self._buf)
            while m is not None:
                line, self._buf = self._buf[:m.start()], self._buf[m.end():]
                if line.strip():
                    return line
                m = _EOL.search(self._buf)
            if len(self._buf) > MAX_LINE:
                line, self._buf = self._buf, b""
                return line
            t_call = clock.monotonic()
            remaining = deadline - t_call
            if remaining <= 0:
                return None
            want = min(self.poll_s, max(remaining, 0.001))
            if self._timeout > want or want - self._timeout > 5e-4:  # wake up by the deadline, never after
                self.port.timeout = self._timeout = want
            try:
                waiting = int(self.port.in_waiting or 0)
                chunk = self.port.read(max(1, waiting))
            except IO_ERRORS as exc:
                raise DeviceError(f"{self.name} at {self.url}: read failed ({exc})") from None
            if chunk:
                self._got(chunk, False, t_call)
            elif self.capture is not None:  # a read that timed out: the replay needs it too
                self.capture.chunk(clock.monotonic(), "rx", b"", t_call=t_call)

    def _got(self, chunk: bytes, ready: bool, t_call: float | None = None) -> None:
        """``chunk`` read; ``ready``: read by :meth:`pull` (bytes already waiting, never
        waits); else ``t_call``: when the read (which could wait) was issued."""
        self.line_t = t = clock.monotonic()
        self._buf += chunk
        if self.capture is not None:
            self.capture.chunk(t, "rx", chunk, ready, None if ready else t_call)

    def close(self) -> None:
        try:
            self.port.close()
        except IO_ERRORS:
            pass
        if self.capture is not None:
            self.capture.close()


class SerialDevice:
    """A bench driver on a serial link (:class:`bench.valves.ValveController`,
    :class:`bench.ohaus.driver.OhausScout`): ``open()`` makes the link, ``close()`` ends it, and
    ``with Driver(...) as d:`` does both, closing on every exit path."""

    def open(self) -> Self:
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()
