"""Driver for OHAUS Scout balances (Scout STX/SPX, Scout Pro, Navigator variants).

Commands are case-sensitive ASCII ended by CR LF: ``IP`` print now, ``P`` print,
``SP`` print when stable, ``CP`` continuous print, ``0P`` stop, ``Z`` zero, ``T`` tare,
``PU`` print unit, ``xU`` set unit, ``PV`` version. ``ES`` means the balance refused a
command; settings commands may answer ``OK!``. A weight line is a right-justified
signed number, a space, the unit, then ``?`` when unstable (``      12.34 g ?``).

A balance reading in grams is a force in gram-force: the session converts at the
boundary and keeps units in column names.
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

from bench.serial_link import SerialLink
from tpods.errors import DeviceError, UserError

TO_GRAMS = {"g": 1.0, "kg": 1000.0, "mg": 1e-3, "ct": 0.2, "oz": 28.349523125,
            "lb": 453.59237, "ozt": 31.1034768, "dwt": 1.55517384, "gn": 0.06479891,
            "tl": 37.429, "mom": 3.75}
"""Grams per unit for the units a Scout prints (``tl``: Hong Kong tael)."""

_KNOWN_UNITS = {u.lower(): u for u in TO_GRAMS} | {"n": "N", "pcs": "PCS", "%": "%"}
_FLAGS = {"?", "n", "g", "net", "gross", "gs", "nt", "t", "tare", "st", "us"}
_UNSTABLE_FLAGS = {"?", "us"}
_WEIGHT = re.compile(
    r"^\s*(?P<pre>\?\s*)?(?P<sign>[-+])?\s*(?P<num>\d+(?:[.,]\d*)?|[.,]\d+)"
    r"\s*(?P<unit>%|[A-Za-z]+(?::[A-Za-z]+)?)(?P<rest>.*)$")


@dataclass(frozen=True)
class Reading:
    """One balance reading: ``value`` in ``unit``, ``stable`` flag, host monotonic time ``t``."""

    value: float
    unit: str
    stable: bool
    t: float = math.nan

    @property
    def grams(self) -> float | None:
        """The reading in grams (gram-force on a thrust bench), None for a non-mass unit."""
        f = TO_GRAMS.get(self.unit)
        return None if f is None else self.value * f


def parse_weight_line(line: bytes | str, t: float = math.nan) -> Reading | None:
    """Parse one weight line of a Scout, Scout Pro or Navigator; None if it is not one.

    Tolerates leading/trailing spaces, a sign separated from the digits, a decimal
    comma, the unit glued to the number, ``?`` anywhere after the number (or before
    it), and net/gross indicators (``N``, ``G``, ``NET``). Rejects partial lines (no
    unit), unknown units, stray characters and non-finite numbers.
    """
    if isinstance(line, bytes):
        try:
            line = line.decode("ascii")
        except UnicodeDecodeError:
            return None
    line = line.strip("\r\n\x00")
    if not line.isprintable():
        return None
    m = _WEIGHT.match(line)
    if m is None:
        return None
    unit = _KNOWN_UNITS.get(m["unit"].lower())
    if unit is None:
        return None
    rest = m["rest"].replace("?", " ? ").split()
    if any(tok.lower() not in _FLAGS for tok in rest):
        return None
    stable = m["pre"] is None and not any(tok.lower() in _UNSTABLE_FLAGS for tok in rest)
    value = float(m["num"].replace(",", "."))
    if m["sign"] == "-":
        value = -value
    if not math.isfinite(value):
        return None
    return Reading(value, unit, stable, t)


class OhausScout:
    """An OHAUS Scout balance on a serial line.

    Args:
        url: pyserial URL or device path, or an open port-like object.
        baudrate, bytesize, parity, stopbits: line settings (Scout: 9600 8N1; the
            Scout Pro USB adapter defaults to 2400 7N1).
        timeout: seconds to wait for a reply to ``IP``/``P``/``PU``/``PV``.
        stable_timeout: seconds to wait for a stable reading after ``SP``.
        ack_timeout: seconds to wait for an optional ``OK!``/``ES`` after a setting.
        silence_timeout: in continuous print, no valid reading for this long is a
            lost balance (DeviceError).
        xonxoff, rtscts: handshake (off by default).

    Garbage lines are counted in ``n_garbage`` (the first few kept in
    ``garbage_examples``) and skipped; ``ES`` answers raise DeviceError from commands.
    """

    def __init__(self, url: str | Any, baudrate: int = 9600, bytesize: int = 8,
                 parity: str = "N", stopbits: float = 1, timeout: float = 2.0,
                 stable_timeout: float = 10.0, ack_timeout: float = 0.3,
                 silence_timeout: float = 2.0, xonxoff: bool = False,
                 rtscts: bool = False) -> None:
        self.url = url
        self.settings = dict(baudrate=baudrate, bytesize=bytesize, parity=parity,
                             stopbits=stopbits, xonxoff=xonxoff, rtscts=rtscts)
        self.timeout = timeout
        self.stable_timeout = stable_timeout
        self.ack_timeout = ack_timeout
        self.silence_timeout = silence_timeout
        self.n_garbage = 0
        self.n_readings = 0
        self.garbage_examples: list[bytes] = []
        self.continuous = False
        self._last_valid = math.nan
        self._link: SerialLink | None = None

    # ------------------------------------------------------------ lifecycle
    def open(self) -> OhausScout:
        if self._link is None:
            self._link = SerialLink(self.url, "OHAUS balance", **self.settings)
        return self

    def close(self) -> None:
        if self._link is not None:
            if self.continuous:
                try:
                    self.stop_continuous()
                except DeviceError:
                    pass
            self._link.close()
            self._link = None

    def __enter__(self) -> OhausScout:
        return self.open()

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def link(self) -> SerialLink:
        if self._link is None:
            self.open()
        return self._link  # type: ignore[return-value]

    # ------------------------------------------------------------ transport
    def _send(self, cmd: str) -> None:
        self.link.write(cmd.encode("ascii") + b"\r\n")

    def _garbage(self, raw: bytes) -> None:
        self.n_garbage += 1
        if len(self.garbage_examples) < 5:
            self.garbage_examples.append(raw[:80])

    def _timeout_error(self, what: str, seconds: float) -> DeviceError:
        return DeviceError(f"OHAUS balance at {self.link.url} sent no {what} within {seconds:g} s "
                           f"(is it on, connected, and set to the same baud rate and format?)")

    def _no_continuous(self, cmd: str) -> None:
        if self.continuous:
            raise UserError(f"stop continuous printing before sending {cmd!r}")

    def read(self, mode: str = "IP", timeout: float | None = None) -> Reading:
        """One reading: ``IP`` now (stable or not), ``P`` the display, ``SP`` when stable."""
        if mode not in ("IP", "P", "SP"):
            raise UserError(f"read mode must be IP, P or SP, not {mode!r}")
        self._no_continuous(mode)
        if timeout is None:
            timeout = self.stable_timeout if mode == "SP" else self.timeout
        self.link.reset_input()
        self._send(mode)
        deadline = time.monotonic() + timeout
        while True:
            raw = self.link.readline(deadline)
            if raw is None:
                raise self._timeout_error(f"reading after {mode!r}", timeout)
            text = raw.strip()
            if text == b"ES":
                raise DeviceError(f"OHAUS balance refused {mode!r} (ES)")
            if text == b"OK!":
                continue
            r = parse_weight_line(raw, time.monotonic())
            if r is None:
                self._garbage(raw)
                continue
            self.n_readings += 1
            return r

    def _setting(self, cmd: str) -> bool:
        """Send a settings command; True if acknowledged with OK!, False if no answer."""
        self._no_continuous(cmd)
        self.link.reset_input()
        self._send(cmd)
        deadline = time.monotonic() + self.ack_timeout
        while True:
            raw = self.link.readline(deadline)
            if raw is None:
                return False
            text = raw.strip()
            if text == b"OK!":
                return True
            if text == b"ES":
                raise DeviceError(f"OHAUS balance refused {cmd!r} (ES)")
            self._garbage(raw)

    def _reply_line(self, cmd: str) -> str:
        self._no_continuous(cmd)
        self.link.reset_input()
        self._send(cmd)
        deadline = time.monotonic() + self.timeout
        while True:
            raw = self.link.readline(deadline)
            if raw is None:
                raise self._timeout_error(f"answer to {cmd!r}", self.timeout)
            text = raw.decode("ascii", "replace").strip()
            if text == "ES":
                raise DeviceError(f"OHAUS balance refused {cmd!r} (ES)")
            if text and text != "OK!" and text.isprintable():
                return text
            self._garbage(raw)

    # -------------------------------------------------------------- commands
    def zero(self) -> bool:
        """``Z``: zero the balance (True if it answered OK!)."""
        return self._setting("Z")

    def tare(self) -> bool:
        """``T``: tare (True if it answered OK!)."""
        return self._setting("T")

    def unit(self) -> str:
        """``PU``: the current unit symbol."""
        text = self._reply_line("PU")
        r = parse_weight_line(text)
        return r.unit if r is not None else text.split()[0]

    def set_unit(self, unit: int | str) -> bool:
        """``xU``: select unit number ``x`` (model-specific; 1 is grams, ``"g"`` accepted)."""
        if isinstance(unit, str):
            if unit != "g":
                raise UserError("set_unit takes the balance's unit number; only 'g' (1) is known by name")
            unit = 1
        if not 1 <= int(unit) <= 99:
            raise UserError(f"unit number must be 1-99, got {unit}")
        return self._setting(f"{int(unit)}U")

    def version(self) -> str:
        """``PV``: the version line(s), joined with `` | ``."""
        first = self._reply_line("PV")
        lines = [first]
        deadline = time.monotonic() + self.ack_timeout
        while (raw := self.link.readline(deadline)) is not None:
            text = raw.decode("ascii", "replace").strip()
            if text.isprintable():
                lines.append(text)
        return " | ".join(lines)

    # ---------------------------------------------------- continuous print
    def start_continuous(self) -> None:
        """``CP``: the balance prints every reading until ``stop_continuous``."""
        self.link.reset_input()
        self._send("CP")
        self.continuous = True
        self._last_valid = time.monotonic()

    def stop_continuous(self) -> None:
        """``0P``: stop printing; drop what is still in flight."""
        self._send("0P")
        self.continuous = False
        time.sleep(0.05)
        self.link.reset_input()

    def next_reading(self, deadline: float) -> Reading | None:
        """Next valid reading (host time in ``.t``), or None when ``deadline`` (monotonic) passes.

        Raises DeviceError when no valid reading arrived for ``silence_timeout``.
        """
        while True:
            limit = min(deadline, self._last_valid + self.silence_timeout) \
                if math.isfinite(self._last_valid) else deadline
            raw = self.link.readline(limit)
            now = time.monotonic()
            if raw is None:
                if now >= deadline:
                    return None
                raise DeviceError(f"OHAUS balance at {self.link.url} went silent: no valid reading "
                                  f"for {self.silence_timeout:g} s")
            r = parse_weight_line(raw, now)
            if r is None:
                if raw.strip() == b"ES" and self.continuous:
                    raise DeviceError("OHAUS balance refused continuous printing (ES to 'CP'); "
                                      "enable continuous/auto print in its menu or use another model")
                if raw.strip() != b"OK!":
                    self._garbage(raw)
                continue
            self._last_valid = now
            self.n_readings += 1
            return r

    def received(self) -> list[Reading]:
        """Valid readings already received but not yet read (never waits).

        A busy host may read lines some time after the balance printed them; a caller
        that switches phase (settle -> dwell) drains these first so they stay with the
        phase in which they were printed.
        """
        self.link.pull()
        out = []
        while True:
            r = self.next_reading(-math.inf)
            if r is None:
                return out
            out.append(r)

    def readings(self, duration_s: float | None = None) -> Iterator[Reading]:
        """Iterate continuous-print readings for ``duration_s`` seconds (None: forever)."""
        if not self.continuous:
            self.start_continuous()
        end = math.inf if duration_s is None else time.monotonic() + duration_s
        while True:
            r = self.next_reading(min(end, time.monotonic() + 3600.0))
            if r is None:
                if time.monotonic() >= end:
                    return
                continue
            yield r
