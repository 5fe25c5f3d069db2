"""Driver for OHAUS Scout balances (Scout STX/SPX, Scout Pro, Navigator variants).

Commands are case-sensitive ASCII ended by CR LF: ``IP`` print now, ``P`` print,
``SP`` print when stable, ``CP`` continuous print, ``0P`` stop, ``Z`` zero, ``T`` tare,
``PU`` print unit, ``xU`` set unit, ``PV`` version. ``ES`` means the balance refused a
command; settings commands may answer ``OK!``. What a printed line is (number, unit,
stability, legends) is decided by :mod:`bench.ohaus_lines` (:func:`parse_line`,
:func:`parse_weight_line`, :class:`Reading`, re-exported here; docs/valve-protocol.md,
"OHAUS balance lines").

A balance reading in grams is a force in gram-force: the session converts at the
boundary and keeps units in column names.

Acquisition (``start_continuous`` / ``next_reading`` / ``stop_continuous``) has three
modes. ``"continuous"``: ``CP``, then every line the balance prints; ``ES`` to ``CP``
or silence is a DeviceError. ``"poll"``: one ``IP`` per reading, the next sent when the
reply (or garbage in its place) arrived; nothing is buffered. ``"auto"`` (default):
``CP``, and if the balance answers ``ES`` (continuous print disabled in its menu, or a
model without it) or prints no valid reading within ``probe_s``, poll instead;
``mode_in_use`` and ``fallback_reason`` say what happened. Polling at 9600 baud is
wire-bound at about 50 readings/s (18 bytes per exchange); a balance that updates
its display more slowly answers repeated ``IP`` with repeated samples, so set
``poll_interval_s`` to its update period when the readings must be independent.
"""

from __future__ import annotations

import math
import re
from collections import deque
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from bench import clock
from bench.ohaus_lines import (
    GROSS,
    KNOWN_UNITS,
    NET,
    TO_GRAMS,
    LineResult,
    Reading,
    parse_line,
    parse_weight_line,
)
from bench.serial_link import SerialDevice, SerialLink
from common.errors import DeviceError, UserError

__all__ = ["ACQUISITION_MODES", "GROSS", "NET", "TO_GRAMS", "LineResult", "NotABalance",
           "NotALoadReading", "OhausScout", "Reading", "parse_line", "parse_weight_line"]


class NotALoadReading(DeviceError):
    """The balance printed only lines that are not the load on the pan (tare, preset tare,
    totals, or the other legend than the one being acquired)."""


class NotABalance(NotALoadReading):
    """The device on the balance's port answers like another device (the TPODS valve
    controller): no reading will ever come, so the caller stops at once."""


# what a TPODS valve controller (protocol v1, docs/valve-protocol.md) answers: an OHAUS
# balance never sends these lines
_VALVE_REPLY = re.compile(rb"^(ERR( |$)|TPODS-VALVES |STATE( |$)|PONG$|OK$)")

_UNSET = object()

ACQUISITION_MODES = ("auto", "continuous", "poll")
"""How :meth:`OhausScout.start_continuous` acquires readings (see the module docstring)."""


class OhausScout(SerialDevice):
    """An OHAUS Scout balance on a serial line.

    Args:
        url: pyserial URL or device path, or an open port-like object.
        baudrate, bytesize, parity, stopbits: line settings (Scout: 9600 8N1; the
            Scout Pro USB adapter defaults to 2400 7N1).
        timeout: seconds to wait for a reply to ``IP``/``P``/``PU``/``PV``.
        stable_timeout: seconds to wait for a stable reading after ``SP``.
        ack_timeout: seconds to wait for an optional ``OK!``/``ES`` after a setting.
        silence_timeout: while acquiring, no valid reading for this long is a
            lost balance (DeviceError).
        xonxoff, rtscts: handshake (off by default).
        acquisition: ``"auto"`` (continuous print, polling with ``IP`` if the balance
            refuses it), ``"continuous"`` or ``"poll"``.
        probe_s: in ``"auto"``, seconds to wait for the first printed reading after ``CP``.
        poll_interval_s: when polling, minimum seconds between two ``IP`` (0: as fast as
            the balance answers).

    Garbage lines are counted in ``n_garbage`` (the first few kept in
    ``garbage_examples``) and skipped; ``ES`` answers raise DeviceError from commands.
    Well-formed lines that are not the load on the pan (tare, preset tare, totals: see
    :func:`parse_weight_line`) are counted apart in ``n_skipped_legend`` (examples in
    ``skipped_examples``); while acquiring, a reading whose legend (gross/net/none)
    differs from the first one's is skipped there too (a print template printing both,
    or a tare pressed at the keypad). ``last_error`` holds the reason of the last line
    not used. When only such lines arrive, :class:`NotALoadReading` (a DeviceError) says
    what the balance printed. A line with an empty unit field (print unit off) is read
    in ``verified_unit``, the unit the balance reported to ``PU`` (:meth:`unit`), and
    refused while none is known (``xU`` clears it: unit numbers differ between models).
    When polling, an ``IP`` unanswered after :attr:`poll_reply_timeout` is sent again
    (``n_poll_timeouts``); a valid reading that arrives while no ``IP`` is outstanding
    (a reply later than that) is dropped and counted in ``n_late_replies``.
    """

    def __init__(self, url: str | Any, baudrate: int = 9600, bytesize: int = 8,
                 parity: str = "N", stopbits: float = 1, timeout: float = 2.0,
                 stable_timeout: float = 10.0, ack_timeout: float = 0.3,
                 silence_timeout: float = 2.0, xonxoff: bool = False,
                 rtscts: bool = False, acquisition: str = "auto", probe_s: float = 1.0,
                 poll_interval_s: float = 0.0, capture: str | Path | None = None) -> None:
        if acquisition not in ACQUISITION_MODES:
            raise UserError(f"balance acquisition must be one of {', '.join(ACQUISITION_MODES)}, "
                            f"not {acquisition!r}")
        if not (probe_s > 0 and poll_interval_s >= 0):
            raise UserError("probe_s must be positive and poll_interval_s non-negative")
        self.url = url
        self.settings = dict(baudrate=baudrate, bytesize=bytesize, parity=parity,
                             stopbits=stopbits, xonxoff=xonxoff, rtscts=rtscts)
        self.capture = capture
        """File receiving a serial transcript of the link (:mod:`bench.capture`), or None."""
        self.timeout = timeout
        self.stable_timeout = stable_timeout
        self.ack_timeout = ack_timeout
        self.silence_timeout = silence_timeout
        self.n_garbage = 0
        self.n_readings = 0
        self.garbage_examples: list[bytes] = []
        self.n_skipped_legend = 0
        self.skipped_examples: list[bytes] = []
        self.last_error = ""
        """Why the last line not used was refused or skipped."""
        self.verified_unit: str | None = None
        """The unit the balance reported to ``PU``; None until :meth:`unit` succeeded."""
        self._skipped_since_valid = 0
        self._last_skipped = b""
        self._legend_lock: Any = _UNSET
        self.continuous = False
        """True while ``CP`` printing is on."""
        self.acquisition = acquisition
        self.probe_s = probe_s
        self.poll_interval_s = poll_interval_s
        self.mode_in_use: str | None = None
        """``"continuous"`` or ``"poll"``: the mode of the last ``start_continuous``."""
        self.fallback_reason: str | None = None
        """Why ``"auto"`` fell back to polling (``"ES to CP"``, ...), None if it did not."""
        self.poll_rate_hz = math.nan
        """Readings per second when polling started (median of five ``IP`` exchanges)."""
        self.n_poll_timeouts = 0
        self.n_late_replies = 0
        self.n_dropped = 0
        self._polling = False
        self._outstanding = False
        self._t_sent = math.nan
        self._next_send = -math.inf
        self._rtt = math.nan
        self._pending: deque[Reading] = deque()
        self._last_valid = math.nan
        self._link: SerialLink | None = None

    # ------------------------------------------------------------ lifecycle
    def open(self) -> OhausScout:
        if self._link is None:
            self._link = SerialLink(self.url, "OHAUS balance", capture=self.capture, **self.settings)
        return self

    def close(self) -> None:
        if self._link is not None:
            if self.acquiring:
                try:
                    self.stop_continuous()
                except DeviceError:
                    pass
            self._link.close()
            self._link = None

    @property
    def link(self) -> SerialLink:
        if self._link is None:
            self.open()
        return self._link  # type: ignore[return-value]

    # ------------------------------------------------------------ transport
    def _send(self, cmd: str) -> None:
        self.link.write(cmd.encode("ascii") + b"\r\n")

    def _garbage(self, raw: bytes, reason: str = "") -> None:
        if _VALVE_REPLY.match(raw.strip()):
            raise NotABalance(
                f"the device at {self.url} (--scale) does not answer like an OHAUS balance: it answered "
                f"{raw.strip()[:60].decode('ascii', 'replace')!r}, a TPODS valve controller's reply "
                "(are the valve controller's and the balance's ports swapped?)")
        self.n_garbage += 1
        self.last_error = reason or "not a weight line"
        if len(self.garbage_examples) < 5:
            self.garbage_examples.append(raw[:80])

    def _skipped(self, raw: bytes, reason: str) -> None:
        self.n_skipped_legend += 1
        self._skipped_since_valid += 1
        self._last_skipped = raw.strip()[:80]
        self.last_error = reason
        if len(self.skipped_examples) < 5:
            self.skipped_examples.append(raw[:80])

    def _classify(self, raw: bytes, t: float) -> Reading | None:
        """The load reading in ``raw``, or None (counted as garbage or as skipped)."""
        res = parse_line(raw, t, self.verified_unit)
        if res.kind == "not_load":
            self._skipped(raw, res.reason)
            return None
        if res.reading is None:
            self._garbage(raw, res.reason)
            return None
        r = res.reading
        if self.acquiring:
            if self._legend_lock is _UNSET:
                self._legend_lock = r.legend
            elif r.legend != self._legend_lock:
                self._skipped(raw, f"a {r.legend or 'no-legend'} reading while acquiring "
                                   f"{self._legend_lock or 'no-legend'} readings")
                return None
        self._skipped_since_valid = 0
        return r

    def _not_load_error(self, what: str) -> NotALoadReading:
        text = self._last_skipped.decode("ascii", "replace")
        n = self._skipped_since_valid
        return NotALoadReading(
            f"OHAUS balance at {self.link.url} {what} only lines that are not the load on the pan "
            f"({n} line{'s' if n > 1 else ''}, the last {text!r}: {self.last_error}); set its print output "
            f"to the displayed weight (gross or net) only")

    def _timeout_error(self, what: str, seconds: float) -> DeviceError:
        why = f"; last line refused: {self.last_error}" if self.last_error else ""
        return DeviceError(f"OHAUS balance at {self.link.url} sent no {what} within {seconds:g} s "
                           f"(is it on, connected, and set to the same baud rate and format?{why})")

    def _no_continuous(self, cmd: str) -> None:
        if self.continuous:
            raise UserError(f"stop continuous printing before sending {cmd!r}")
        if self._polling and self._outstanding:  # keep the reply in flight for next_reading
            r = self._next_polled(-math.inf)
            if r is not None:
                self._pending.append(r)

    def read(self, mode: str = "IP", timeout: float | None = None) -> Reading:
        """One reading: ``IP`` now (stable or not), ``P`` the display, ``SP`` when stable."""
        if mode not in ("IP", "P", "SP"):
            raise UserError(f"read mode must be IP, P or SP, not {mode!r}")
        self._no_continuous(mode)
        if timeout is None:
            timeout = self.stable_timeout if mode == "SP" else self.timeout
        self.link.reset_input()
        self._send(mode)
        deadline = clock.monotonic() + timeout
        self._skipped_since_valid = 0
        self.last_error = ""
        while True:
            raw = self.link.readline(deadline)
            if raw is None:
                if self._skipped_since_valid:
                    raise self._not_load_error(f"answered {mode!r} with")
                raise self._timeout_error(f"reading after {mode!r}", timeout)
            text = raw.strip()
            if text == b"ES":
                raise DeviceError(f"OHAUS balance refused {mode!r} (ES)")
            if text == b"OK!":
                continue
            n_skipped = self.n_skipped_legend
            r = self._classify(raw, self.link.line_t)
            if r is None:
                if self.n_skipped_legend > n_skipped:  # a print template may follow with the load
                    deadline = min(deadline, clock.monotonic() + self.ack_timeout)
                continue
            self.n_readings += 1
            return r

    def _replies(self, cmd: str, timeout_s: float) -> Iterator[bytes]:
        """Send ``cmd`` (continuous print stopped, stale input dropped) and yield the lines
        that come back within ``timeout_s``."""
        self._no_continuous(cmd)
        self.link.reset_input()
        self._send(cmd)
        deadline = clock.monotonic() + timeout_s
        while (raw := self.link.readline(deadline)) is not None:
            yield raw

    def _setting(self, cmd: str) -> bool:
        """Send a settings command; True if acknowledged with OK!, False if no answer."""
        for raw in self._replies(cmd, self.ack_timeout):
            text = raw.strip()
            if text == b"OK!":
                return True
            if text == b"ES":
                raise DeviceError(f"OHAUS balance refused {cmd!r} (ES)")
            self._garbage(raw)
        return False

    def _reply_line(self, cmd: str) -> str:
        for raw in self._replies(cmd, self.timeout):
            text = raw.decode("ascii", "replace").strip()
            if text == "ES":
                raise DeviceError(f"OHAUS balance refused {cmd!r} (ES)")
            if text and text != "OK!" and text.isprintable() and not _VALVE_REPLY.match(raw.strip()):
                return text
            self._garbage(raw)
        raise self._timeout_error(f"answer to {cmd!r}", self.timeout)

    # -------------------------------------------------------------- commands
    def zero(self) -> bool:
        """``Z``: zero the balance (True if it answered OK!)."""
        return self._setting("Z")

    def tare(self) -> bool:
        """``T``: tare (True if it answered OK!)."""
        return self._setting("T")

    def unit(self) -> str:
        """``PU``: the current unit symbol; a known one becomes ``verified_unit`` (the unit
        of lines printed with the unit field off)."""
        self.verified_unit = None
        text = self._reply_line("PU")
        r = parse_weight_line(text)
        sym = r.unit if r is not None else text.split()[0]
        self.verified_unit = KNOWN_UNITS.get(sym.lower())
        return sym

    def set_unit(self, unit: int | str) -> bool:
        """``xU``: select unit number ``x`` (model-specific: 1 is grams on a Scout, kilograms
        on a Defender 5000; ``"g"`` sends 1). Clears ``verified_unit``: call :meth:`unit` to
        verify."""
        if isinstance(unit, str):
            if unit != "g":
                raise UserError("set_unit takes the balance's unit number; only 'g' (1) is known by name")
            unit = 1
        if not 1 <= int(unit) <= 99:
            raise UserError(f"unit number must be 1-99, got {unit}")
        self.verified_unit = None
        return self._setting(f"{int(unit)}U")

    def version(self) -> str:
        """``PV``: the version line(s), joined with `` | ``."""
        first = self._reply_line("PV")
        lines = [first]
        deadline = clock.monotonic() + self.ack_timeout
        while (raw := self.link.readline(deadline)) is not None:
            text = raw.decode("ascii", "replace").strip()
            if text.isprintable():
                lines.append(text)
        return " | ".join(lines)

    # ----------------------------------------------------------- acquisition
    @property
    def acquiring(self) -> bool:
        """True between ``start_continuous`` and ``stop_continuous`` (printing or polling)."""
        return self.continuous or self._polling

    @property
    def poll_reply_timeout(self) -> float:
        """Seconds to wait for the reply to one ``IP`` before sending it again:
        five measured round trips, at least 0.25 s, at most ``timeout``."""
        rtt = self._rtt if math.isfinite(self._rtt) else 0.0
        return min(self.timeout, max(0.25, 5.0 * rtt))

    @property
    def fallback_message(self) -> str | None:
        """One line for the operator when ``"auto"`` fell back to polling, else None."""
        if self.fallback_reason is None:
            return None
        return f"balance {self._no_cp(self.fallback_reason)}: polling with IP at ~{self.poll_rate_hz:.0f} readings/s"

    @staticmethod
    def _no_cp(reason: str) -> str:
        return ("refused continuous print (ES to CP)" if reason == "ES to CP"
                else f"printed nothing after CP ({reason})")

    def acquisition_info(self) -> dict[str, Any]:
        """Requested and used acquisition mode, fallback reason, poll rate and counts
        (for run.json)."""
        return {"requested": self.acquisition, "mode": self.mode_in_use,
                "fallback": self.fallback_reason,
                "poll_rate_hz": round(self.poll_rate_hz, 2) if math.isfinite(self.poll_rate_hz) else None,
                "poll_interval_s": self.poll_interval_s if self.mode_in_use == "poll" else None,
                "poll_timeouts": self.n_poll_timeouts, "late_replies_dropped": self.n_late_replies,
                "dropped_at_stop": self.n_dropped}

    def start_continuous(self) -> None:
        """Start acquiring readings in the configured mode (see the module docstring).

        ``"continuous"``: send ``CP`` and return. ``"auto"``: send ``CP`` and wait up to
        ``probe_s`` for the first printed reading (kept for :meth:`next_reading`); on
        ``ES`` or silence (then ``0P`` is sent) poll instead. ``"poll"`` (or the
        fallback): take five readings with ``IP`` (kept for :meth:`next_reading`) to
        measure ``poll_rate_hz``; raises DeviceError when the balance cannot be polled.
        """
        self._pending.clear()
        self.fallback_reason = None
        self._legend_lock = _UNSET
        self._skipped_since_valid = 0
        if self.acquisition == "poll":
            self._start_polling(None)
            return
        self.link.reset_input()
        self._send("CP")
        self.continuous = True
        self.mode_in_use = "continuous"
        self._last_valid = clock.monotonic()
        if self.acquisition == "continuous":
            return
        end = self._last_valid + self.probe_s
        while True:
            raw = self.link.readline(end)
            if raw is None and self._skipped_since_valid:
                self._send("0P")
                self.continuous = False
                raise self._not_load_error("printed after 'CP'")
            if raw is None:
                self._send("0P")  # in case it starts printing later
                self.continuous = False
                clock.sleep(0.05)
                self.link.reset_input()
                self._start_polling(f"no reading within {self.probe_s:g} s")
                return
            text = raw.strip()
            if text == b"ES":
                self.continuous = False
                self._start_polling("ES to CP")
                return
            if text == b"OK!":
                continue
            r = self._classify(raw, self.link.line_t)
            if r is None:
                continue
            self._last_valid = r.t
            self.n_readings += 1
            self._pending.append(r)
            return

    def _start_polling(self, reason: str | None) -> None:
        self.continuous = False
        self._polling = True
        self.mode_in_use = "poll"
        self.fallback_reason = reason
        self._outstanding = False
        self._next_send = -math.inf
        self._rtt = math.nan
        self._last_valid = t = clock.monotonic()
        periods = []
        try:
            for _ in range(5):
                r = self._next_polled(math.inf)
                assert r is not None  # no deadline
                self._pending.append(r)
                periods.append(r.t - t)
                t = r.t
        except DeviceError as exc:
            self._polling = False
            if reason is None:
                raise
            raise DeviceError(f"OHAUS balance {self._no_cp(reason)} and polling with IP failed: "
                              f"{exc}") from None
        self.poll_rate_hz = 1.0 / max(sorted(periods)[len(periods) // 2], 1e-6)

    def stop_continuous(self) -> None:
        """Stop acquiring. Continuous print: ``0P``, drop what is still in flight.
        Polling: wait for the reply to an outstanding ``IP``; readings not read by then
        are dropped and counted in ``n_dropped``."""
        if self._polling:
            try:
                if self._outstanding:
                    r = self._next_polled(-math.inf)
                    if r is not None:
                        self._pending.append(r)
            finally:
                self.n_dropped += len(self._pending)
                self._pending.clear()
                self._polling = self._outstanding = False
            return
        self._pending.clear()
        self._send("0P")
        self.continuous = False
        clock.sleep(0.05)
        self.link.reset_input()

    def _silent_error(self) -> DeviceError:
        if self._skipped_since_valid:
            return self._not_load_error(f"printed for {self.silence_timeout:g} s")
        extra = f" ({self.n_poll_timeouts} IP unanswered)" if self._polling and self.n_poll_timeouts else ""
        return DeviceError(f"OHAUS balance at {self.link.url} went silent: no valid reading "
                           f"for {self.silence_timeout:g} s{extra}")

    def _stray(self, raw: bytes) -> None:
        """A line that arrived while no ``IP`` was outstanding."""
        text = raw.strip()
        if text in (b"OK!", b"ES"):
            return
        res = parse_line(raw, math.nan, self.verified_unit)
        if res.kind == "reading":
            self.n_late_replies += 1
        elif res.kind == "not_load":
            self.n_skipped_legend += 1  # no reply to anything: not counted towards silence
            self.last_error = res.reason
        else:
            self._garbage(raw, res.reason)

    def _next_polled(self, deadline: float) -> Reading | None:
        """Polling: send ``IP`` unless its reply could not arrive before ``deadline``;
        wait for the reply to an outstanding ``IP`` even past ``deadline``."""
        while True:
            now = clock.monotonic()
            silent_at = self._last_valid + self.silence_timeout
            if not self._outstanding:
                if now >= silent_at:
                    raise self._silent_error()
                send_at = max(now, self._next_send)
                rtt = self._rtt if math.isfinite(self._rtt) else 0.0
                if send_at + rtt > deadline or send_at > now:
                    if now >= deadline:
                        return None
                    raw = self.link.readline(min(deadline, send_at if send_at > now else deadline, silent_at))
                    if raw is not None:
                        self._stray(raw)
                    continue
                self.link.pull()  # lines already here are no reply to the IP about to go out
                while (raw := self.link.readline(-math.inf)) is not None:
                    self._stray(raw)
                self._send("IP")
                self._outstanding = True
                self._t_sent = clock.monotonic()
                self._next_send = self._t_sent + self.poll_interval_s
            raw = self.link.readline(min(self._t_sent + self.poll_reply_timeout, silent_at))
            now = clock.monotonic()
            if raw is None:
                self._outstanding = False
                if now >= silent_at:
                    raise self._silent_error()
                self.n_poll_timeouts += 1
                continue
            text = raw.strip()
            if text == b"OK!":
                continue
            if text == b"ES":
                self._outstanding = False
                raise DeviceError("OHAUS balance refused 'IP' (ES): it can be neither polled nor, "
                                  "in this mode, read continuously")
            self._outstanding = False
            r = self._classify(raw, self.link.line_t)
            if r is None:  # the reply, garbled or not a load reading: ask again
                continue
            rtt = now - self._t_sent
            self._rtt = rtt if not math.isfinite(self._rtt) else 0.8 * self._rtt + 0.2 * rtt
            self._last_valid = now
            self.n_readings += 1
            return r

    def next_reading(self, deadline: float) -> Reading | None:
        """Next valid reading (host time of arrival in ``.t``), or None when ``deadline``
        (monotonic) passes.

        Continuous print: the next printed line. Polling: one ``IP``, not sent when its
        reply (at the measured round trip) could not arrive before ``deadline``; the
        reply to an ``IP`` already sent is waited for even past ``deadline``, so it stays
        with the window in which it was requested. Raises DeviceError when no valid
        reading arrived for ``silence_timeout``.
        """
        if self._pending:
            return self._pending.popleft()
        if self._polling:
            return self._next_polled(deadline)
        while True:
            limit = min(deadline, self._last_valid + self.silence_timeout) \
                if math.isfinite(self._last_valid) else deadline
            raw = self.link.readline(limit)
            now = clock.monotonic()
            if raw is None:
                if now >= deadline:
                    return None
                raise self._silent_error()
            text = raw.strip()
            if text == b"ES" and self.continuous:
                raise DeviceError("OHAUS balance refused continuous printing (ES to 'CP'); "
                                  "enable continuous/auto print in its menu, or use the auto or "
                                  "poll acquisition mode")
            if text == b"OK!":
                continue
            r = self._classify(raw, self.link.line_t)
            if r is None:
                continue
            self._last_valid = now
            self.n_readings += 1
            return r

    def received(self) -> list[Reading]:
        """Valid readings already received but not yet read (never waits for new ones).

        A busy host may read lines some time after the balance printed them; a caller
        that switches phase (settle -> dwell) drains these first so they stay with the
        phase in which they were printed. When polling nothing is buffered by design
        (``next_reading`` returns only once the reply to its ``IP`` is in), so this is
        ``[]``, unless an ``IP`` is still outstanding (``next_reading`` interrupted):
        then its reply is waited for and returned here.
        """
        self.link.pull()
        out = []
        while True:
            r = self.next_reading(-math.inf)
            if r is None:
                return out
            out.append(r)

    def readings(self, duration_s: float | None = None) -> Iterator[Reading]:
        """Iterate readings for ``duration_s`` seconds (None: forever), starting
        acquisition first if needed."""
        if not self.acquiring:
            self.start_continuous()
        end = math.inf if duration_s is None else clock.monotonic() + duration_s
        while True:
            r = self.next_reading(min(end, clock.monotonic() + 3600.0))
            if r is None:
                if clock.monotonic() >= end:
                    return
                continue
            yield r
