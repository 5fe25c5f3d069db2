"""Reading an OHAUS balance continuously: continuous print, polling with ``IP``, or both.

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

:class:`OhausAcquisition` holds this half of :class:`bench.ohaus.driver.OhausScout`, which is
the class to use (commands and one-shot reads are in :mod:`bench.ohaus.driver`).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterator
from typing import Any

from bench import clock
from bench.ohaus.lines import Reading, parse_line
from bench.ohaus.replies import _UNSET, OhausLineHandler
from common.errors import DeviceError

__all__ = ["ACQUISITION_MODES", "OhausAcquisition"]

ACQUISITION_MODES = ("auto", "continuous", "poll")
"""How :meth:`OhausScout.start_continuous` acquires readings (see the module docstring)."""


class OhausAcquisition(OhausLineHandler):
    """``start_continuous`` / ``next_reading`` / ``received`` / ``readings`` /
    ``stop_continuous`` of the OHAUS driver, in the modes described in the module
    docstring; the settings and counters it uses are set up by
    :class:`bench.ohaus.driver.OhausScout`."""

    acquisition: str
    probe_s: float
    poll_interval_s: float
    timeout: float
    silence_timeout: float
    n_readings: int
    mode_in_use: str | None
    fallback_reason: str | None
    poll_rate_hz: float
    n_poll_timeouts: int
    n_late_replies: int
    n_dropped: int
    _outstanding: bool
    _t_sent: float
    _next_send: float
    _rtt: float
    _pending: deque[Reading]
    _last_valid: float

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
