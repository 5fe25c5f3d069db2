"""Line-oriented serial link shared by the bench drivers.

Opens any pyserial URL (``/dev/ttyACM0``, ``socket://HOST:PORT``, ``loop://``, a pty
path) with :func:`serial.serial_for_url`, or wraps an already open port-like object
(anything with ``write``, ``read`` and ``in_waiting``: tests pass scripted fakes).
Reads lines against a deadline, so a caller can wait until a given time without
treating the wait as a silent device.
"""

from __future__ import annotations

import re
import time
from typing import Any

import serial

from common.errors import DeviceError

_EOL = re.compile(rb"[\r\n]")
MAX_LINE = 512


class SerialLink:
    """A byte link with a line reader.

    Args:
        port: pyserial URL or an open port-like object.
        name: what the device is, for error messages ("valve controller").
        poll_s: read timeout of one poll, seconds (granularity of deadlines).
        **settings: pyserial settings (baudrate, bytesize, parity, stopbits, ...).
    """

    def __init__(self, port: str | Any, name: str, poll_s: float = 0.02, **settings: Any) -> None:
        self.name = name
        self.poll_s = poll_s
        self._timeout = poll_s
        self._buf = b""
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

    def write(self, data: bytes) -> None:
        try:
            self.port.write(data)
            flush = getattr(self.port, "flush", None)
            if flush is not None:
                flush()
        except OSError as exc:  # serial.SerialException is an OSError
            raise DeviceError(f"{self.name} at {self.url}: write failed ({exc})") from None

    def pull(self) -> None:
        """Move every byte already received by the OS into the line buffer (never waits)."""
        try:
            n = int(self.port.in_waiting or 0)
            if n:
                self._buf += self.port.read(n)
        except OSError as exc:
            raise DeviceError(f"{self.name} at {self.url}: read failed ({exc})") from None

    def reset_input(self) -> None:
        """Drop unread bytes (stale replies, continuous prints)."""
        self._buf = b""
        reset = getattr(self.port, "reset_input_buffer", None)
        if reset is not None:
            try:
                reset()
            except OSError:
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
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return None
            want = min(self.poll_s, max(remaining, 0.001))
            if abs(self._timeout - want) > 5e-4:  # wake up at the deadline, not a poll later
                self.port.timeout = self._timeout = want
            try:
                n = max(1, int(self.port.in_waiting or 0))
                chunk = self.port.read(n)
            except OSError as exc:
                raise DeviceError(f"{self.name} at {self.url}: read failed ({exc})") from None
            if chunk:
                self._buf += chunk

    def close(self) -> None:
        try:
            self.port.close()
        except OSError:
            pass
