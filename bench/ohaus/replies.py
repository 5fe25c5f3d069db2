"""How the OHAUS driver sorts what a balance sends, and the errors that say why.

Every line a balance prints is one of: a load reading (kept), a well-formed line that is
not the load on the pan (tare, preset tare, totals, the other legend: counted as
skipped), garbage (counted), or a TPODS valve controller's reply (the ports are swapped:
:class:`NotABalance` at once). :class:`OhausLineHandler` holds that sorting and the
command framing (ASCII ended by CR LF) for :class:`bench.ohaus.driver.OhausScout`, which is
the class to use; what a line means is decided by :mod:`bench.ohaus.lines`.
"""

from __future__ import annotations

import re
from typing import Any

from bench.ohaus.lines import Reading, parse_line
from bench.serial_link import SerialDevice, SerialLink
from common.errors import DeviceError

__all__ = ["NotABalance", "NotALoadReading", "OhausLineHandler"]


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


class OhausLineHandler(SerialDevice):
    """Command framing and line sorting shared by the OHAUS driver's commands and its
    acquisition; the state it reads and counts is set up by :class:`bench.ohaus.driver.OhausScout`
    (see there for the counters' meaning)."""

    url: str | Any
    link: SerialLink
    n_garbage: int
    garbage_examples: list[bytes]
    n_skipped_legend: int
    skipped_examples: list[bytes]
    last_error: str
    verified_unit: str | None
    continuous: bool
    _polling: bool
    _skipped_since_valid: int
    _last_skipped: bytes
    _legend_lock: Any

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

    @property
    def acquiring(self) -> bool:
        """True between ``start_continuous`` and ``stop_continuous`` (printing or polling)."""
        return self.continuous or self._polling
