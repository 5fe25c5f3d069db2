"""Emulated valve controller speaking protocol v1 (docs/valve-protocol.md).

Usable in-process (``process_line``) or on a pty (:func:`bench.emulators.pty.serve_pty`).
Every change of the duties is logged with a monotonic timestamp and its cause
(``"command"``, ``"watchdog"``), and listeners are called with the new duties, so a
plant simulation can follow the valves and tests can check when they closed.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass


@dataclass(frozen=True)
class DutyChange:
    """One change of the valve duties: monotonic time (s), new duties (%), cause."""

    t: float
    duties: tuple[float, ...]
    cause: str


def _fmt(x: float) -> str:
    return f"{x:g}"


class EmulatedValveController:
    """Protocol-v1 valve board with ``n_channels`` PWM outputs and a watchdog.

    Args:
        n_channels: number of valves.
        firmware: version string returned by ``ID?``.
        clock: monotonic clock in seconds (injectable for tests).
    """

    def __init__(self, n_channels: int = 4, firmware: str = "1.0-emu",
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.n_channels = n_channels
        self.firmware = firmware
        self.clock = clock
        self.freq_hz = 10.0
        self.watchdog_ms = 0
        self._duties = [0.0] * n_channels
        self._last_cmd = clock()
        self._buf = b""
        self._lock = threading.RLock()
        self.log: list[DutyChange] = [DutyChange(self._last_cmd, tuple(self._duties), "start")]
        self.lines: list[tuple[float, str, str]] = []
        """Every (time, command line, reply line) handled."""
        self.watchdog_trips = 0
        self._listeners: list[Callable[[float, tuple[float, ...]], None]] = []

    # ------------------------------------------------------------- state
    @property
    def duties(self) -> tuple[float, ...]:
        """Current duty of each channel in percent (0 = closed).

        Lock-free (the list is replaced, never mutated), so listeners and other
        emulators may read it from any thread without lock-order deadlocks.
        """
        return tuple(self._duties)

    def add_listener(self, callback: Callable[[float, tuple[float, ...]], None]) -> None:
        """Call ``callback(t, new_duties)`` on every change, from the thread making it.

        Called just before ``duties`` switches to the new value (so a listener can
        first advance its own state under the old duties up to ``t``). Keep it short
        and never call back into this emulator's commands from it.
        """
        self._listeners.append(callback)

    def closed_since(self) -> float | None:
        """Monotonic time since which every valve has been closed (None if one is open)."""
        with self._lock:
            if any(self._duties):
                return None
            for ch in reversed(self.log):
                if any(ch.duties):
                    break
                t = ch.t
            return t

    def _set(self, duties: list[float], now: float, cause: str) -> None:
        if duties == self._duties:
            return
        for cb in self._listeners:  # before the change: listeners advance their state
            cb(now, tuple(duties))
        self._duties = duties
        self.log.append(DutyChange(now, tuple(duties), cause))

    # ------------------------------------------------------------ protocol
    def process_line(self, line: str, now: float | None = None) -> str:
        """Handle one command line (without terminator); return the reply line."""
        now = self.clock() if now is None else now
        with self._lock:
            self._check_watchdog(now)
            self._last_cmd = now
            reply = self._dispatch(line.strip(), now)
            self.lines.append((now, line, reply))
            return reply

    def _dispatch(self, line: str, now: float) -> str:
        parts = line.split()
        if not parts:
            return "ERR empty command"
        cmd, args = parts[0].upper(), parts[1:]
        n = self.n_channels

        def num(s: str) -> float:
            v = float(s)
            if not math.isfinite(v):
                raise ValueError(s)
            return v

        try:
            if cmd == "ID?" and not args:
                return f"TPODS-VALVES {self.firmware} {n}"
            if cmd == "PING" and not args:
                return "PONG"
            if cmd == "STATE?" and not args:
                return "STATE " + " ".join(_fmt(d) for d in self._duties)
            if cmd == "OFF" and not args:
                self._set([0.0] * n, now, "command")
                return "OK"
            if cmd == "FREQ" and len(args) == 1:
                hz = num(args[0])
                if not 1 <= hz <= 100:
                    return "ERR frequency must be 1-100 Hz"
                self.freq_hz = hz
                return "OK"
            if cmd == "WDT" and len(args) == 1:
                ms = num(args[0])
                if ms < 0 or ms != int(ms) or ms > 600000:
                    return "ERR watchdog must be 0-600000 ms"
                self.watchdog_ms = int(ms)
                return "OK"
            if cmd == "DUTY" and len(args) == 2:
                ch = int(args[0])
                pct = num(args[1])
                if not 1 <= ch <= n:
                    return f"ERR channel must be 1-{n}"
                if not 0 <= pct <= 100:
                    return "ERR duty must be 0-100"
                new = list(self._duties)
                new[ch - 1] = pct
                self._set(new, now, "command")
                return "OK"
            if cmd == "DUTY*" and len(args) == n:
                vals = [num(a) for a in args]
                if not all(0 <= v <= 100 for v in vals):
                    return "ERR duty must be 0-100"
                self._set(vals, now, "command")
                return "OK"
        except ValueError:
            return "ERR bad number"
        return f"ERR unknown command {line[:40]}"

    def _check_watchdog(self, now: float) -> None:
        if self.watchdog_ms > 0 and now - self._last_cmd > self.watchdog_ms / 1000.0:
            if any(self._duties):
                self.watchdog_trips += 1
                # the valves closed when the watchdog expired, not when we noticed
                self._set([0.0] * self.n_channels, self._last_cmd + self.watchdog_ms / 1000.0,
                          "watchdog")

    # -------------------------------------------------- byte stream (pty)
    def receive(self, data: bytes, now: float) -> bytes:
        """Feed raw bytes; returns the reply bytes (one ``\\n``-ended line per command)."""
        self._buf += data
        out = []
        while b"\n" in self._buf:
            raw, self._buf = self._buf.split(b"\n", 1)
            line = raw.decode("ascii", "replace").strip("\r")
            out.append(self.process_line(line, now) + "\n")
        if len(self._buf) > 256:  # no terminator in sight: drop
            self._buf = b""
            out.append("ERR line too long\n")
        return "".join(out).encode()

    def tick(self, now: float) -> tuple[bytes, float | None]:
        with self._lock:
            self._check_watchdog(now)
            if self.watchdog_ms > 0 and any(self._duties):
                return b"", self._last_cmd + self.watchdog_ms / 1000.0 + 1e-4
        return b"", None
