"""Driver for OHAUS Scout balances (Scout STX/SPX, Scout Pro, Navigator variants).

Commands are case-sensitive ASCII ended by CR LF: ``IP`` print now, ``P`` print,
``SP`` print when stable, ``CP`` continuous print, ``0P`` stop, ``Z`` zero, ``T`` tare,
``PU`` print unit, ``xU`` set unit, ``PV`` version. ``ES`` means the balance refused a
command; settings commands may answer ``OK!``. What a printed line is (number, unit,
stability, legends) is decided by :mod:`bench.ohaus.lines` (:func:`parse_line`,
:func:`parse_weight_line`, :class:`Reading`, re-exported here; docs/valve-protocol.md,
"OHAUS balance lines").

A balance reading in grams is a force in gram-force: the session converts at the
boundary and keeps units in column names.

Reading continuously (``start_continuous`` / ``next_reading`` / ``stop_continuous``:
continuous print, polling with ``IP``, or ``"auto"`` choosing between them) is
described in :mod:`bench.ohaus.acquisition`; how each line is sorted (reading, skipped,
garbage, a valve controller's reply) is in :mod:`bench.ohaus.replies`. Both are parts of
:class:`OhausScout`, the class to use; their public names are re-exported here.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from bench import clock
from bench.ohaus.acquisition import ACQUISITION_MODES, OhausAcquisition
from bench.ohaus.lines import (
    GROSS,
    KNOWN_UNITS,
    NET,
    TO_GRAMS,
    LineResult,
    Reading,
    parse_line,
    parse_weight_line,
)
from bench.ohaus.replies import _UNSET, _VALVE_REPLY, NotABalance, NotALoadReading
from bench.serial_link import SerialLink
from common.errors import DeviceError, UserError

__all__ = ["ACQUISITION_MODES", "GROSS", "NET", "TO_GRAMS", "LineResult", "NotABalance",
           "NotALoadReading", "OhausScout", "Reading", "parse_line", "parse_weight_line"]


class OhausScout(OhausAcquisition):
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
