"""Driver for the TPODS valve controller, protocol v1 (docs/valve-protocol.md).

One ASCII command line ended by ``\\n``, exactly one reply line. Works over any
pyserial URL: a USB serial board, a module's Wi-Fi bridge (``socket://HOST:PORT``)
or an emulator on a pty. ``safe()`` is the structural guarantee that the valves
close: it arms the controller watchdog, feeds it from a thread while the caller is
alive, and on every exit path (normal end, exception, Ctrl-C) sends ``OFF`` and
confirms with ``STATE?``.
"""

from __future__ import annotations

import contextlib
import math
import re
import threading
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bench import clock
from bench.serial_link import SerialDevice, SerialLink
from common.errors import DeviceError, UserError


@dataclass(frozen=True)
class ValveIdentity:
    """What ``ID?`` answered."""

    model: str
    firmware: str
    n_channels: int


def _fmt(x: float) -> str:
    return f"{x:.3f}".rstrip("0").rstrip(".")


# Telnet commands (RFC 854): IAC WILL/WONT/DO/DONT <option>, IAC SB ... IAC SE, IAC <command>.
# A Wi-Fi bridge in telnet mode sends some on connect; the option byte may be printable.
_TELNET = re.compile(rb"\xff(?:[\xfb-\xfe].|\xfa.*?\xff\xf0|[\xf0-\xf9])", re.S)
_NOT_TEXT = re.compile(rb"[^\t\x20-\x7e]")


def clean_reply(raw: bytes) -> tuple[str, int]:
    """A reply line as text, without what real links add around it.

    Drops telnet negotiation, NUL and every other control or non-ASCII byte (a
    USB-serial adapter or a board resetting as the port opens delivers such bytes
    first), then surrounding whitespace. Returns ``(text, number of bytes dropped)``.
    """
    kept = _NOT_TEXT.sub(b"", _TELNET.sub(b"", raw))
    return kept.decode("ascii").strip(), len(raw) - len(kept)


class ValveController(SerialDevice):
    """Protocol-v1 valve controller.

    Args:
        url: pyserial URL or device path, or an open port-like object.
        baudrate: serial speed (ignored by sockets and ptys).
        timeout: seconds to wait for each reply.
        duty_limits: ``(low, high)`` percent: an open valve's duty must lie in this
            range (0 always means closed); violations raise UserError before sending.
        boot_s: how long after opening the port a board may take to start answering:
            an Arduino Uno/Nano/Mega resets when the port opens (DTR) and its sketch
            runs 1.5-2 s later. Before the first command ``PING`` is sent (again every
            0.5 s) until ``PONG`` comes back or this time has passed; lines before it
            (boot banner, replies to commands the board half-heard) are skipped.
            Default 3 s when the driver opens ``url`` itself, 0 (no wait) for a port
            object passed in.
        capture: record a serial transcript of the link into this file
            (:mod:`bench.capture`; replay it with ``replay://PATH``).
        **serial_settings: other pyserial settings.

    Use as a context manager; ``identify()`` before channel commands (it learns the
    number of channels). ``dropped_bytes`` counts bytes removed from replies (NUL,
    telnet negotiation, other non-text bytes), ``skipped_lines`` lines that were not
    a reply (boot banner, an echo of the command).
    """

    def __init__(self, url: str | Any, baudrate: int = 115200, timeout: float = 1.0,
                 duty_limits: tuple[float, float] = (0.0, 100.0), boot_s: float | None = None,
                 capture: str | Path | None = None, **serial_settings: Any) -> None:
        self.url = url
        self.baudrate = baudrate
        self.timeout = timeout
        self.duty_limits = duty_limits
        self.boot_s = (3.0 if isinstance(url, str) else 0.0) if boot_s is None else float(boot_s)
        self.serial_settings = serial_settings
        self.capture = capture
        self.n_channels: int | None = None
        self.identity: ValveIdentity | None = None
        self._link: SerialLink | None = None
        self._lock = threading.RLock()
        self._opened_t = 0.0
        self._sync_pending = False
        self.dropped_bytes = 0
        self.skipped_lines = 0
        self.last_command_t = 0.0
        """Monotonic time of the last command answered (any thread)."""
        self.last_caller_t = 0.0
        """Monotonic time of the last command answered, watchdog feeds excluded."""

    # ------------------------------------------------------------ lifecycle
    def open(self) -> ValveController:
        if self._link is None:
            self._link = SerialLink(self.url, "valve controller", baudrate=self.baudrate,
                                    capture=self.capture, keepalive=b"PING\n", **self.serial_settings)
            self._opened_t = clock.monotonic()
            self._sync_pending = self.boot_s > 0
        return self

    def close(self) -> None:
        if self._link is not None:
            self._link.close()
            self._link = None

    # ------------------------------------------------------------ transport
    def command(self, line: str, *, _feeder: bool = False) -> str:
        """Send one command line; return the reply line. ``ERR ...`` raises DeviceError."""
        if self._link is None:
            self.open()
        link = self._link
        with self._lock:
            if self._sync_pending:
                self._sync_pending = False
                self._wait_boot(link)
            reply = self._exchange(link, line, self.timeout)
            if reply is None:
                partial = clean_reply(link.pending)[0]
                if partial:
                    raise DeviceError(f"valve controller at {link.url} answered {line!r} with {partial!r} "
                                      f"but no end of line within {self.timeout:g} s (replies end with \\n)")
                raise DeviceError(f"valve controller at {link.url} did not answer {line!r} "
                                  f"within {self.timeout:g} s")
            self.last_command_t = link.line_t  # when the reply was read
            if not _feeder:
                self.last_caller_t = self.last_command_t
        if reply.startswith("ERR"):
            raise DeviceError(f"valve controller refused {line!r}: {reply}")
        return reply

    def _exchange(self, link: SerialLink, line: str, timeout: float) -> str | None:
        """Send ``line``; the first reply line within ``timeout`` (None: none came).

        Lines that hold nothing but noise and an exact echo of ``line`` are skipped.
        """
        link.reset_input()  # a late reply to an earlier, timed-out command
        link.write(line.encode("ascii") + b"\n")
        deadline = clock.monotonic() + timeout
        while True:
            raw = link.readline(deadline)
            if raw is None:
                return None
            text, dropped = clean_reply(raw)
            self.dropped_bytes += dropped
            if text and text != line:
                return text
            self.skipped_lines += bool(text)

    def _wait_boot(self, link: SerialLink) -> None:
        """Before the first command: PING until PONG, for up to ``boot_s`` after opening."""
        end = self._opened_t + self.boot_s
        heard = None
        sent = 0
        while True:
            reply = self._exchange(link, "PING", min(self.timeout, 0.5))
            sent += 1
            if reply == "PONG":
                return
            if reply is not None:
                heard = reply
                self.skipped_lines += 1
            if clock.monotonic() >= end:
                break
        if heard is None:
            raise DeviceError(
                f"valve controller at {link.url} sent nothing in the {clock.monotonic() - self._opened_t:.1f} s "
                f"after the port opened ({sent} PINGs; a board that resets on open answers within about 2 s): "
                f"check the port, the cable and the baud rate")
        # it talks but never said PONG: let the caller's command report what it answers

    def _expect_ok(self, line: str) -> None:
        reply = self.command(line)
        if reply != "OK":
            raise DeviceError(f"valve controller answered {reply!r} to {line!r} (expected OK)")

    # -------------------------------------------------------------- commands
    def identify(self) -> ValveIdentity:
        """``ID?``: model, firmware and channel count (remembered for later checks)."""
        reply = self.command("ID?")
        parts = reply.split()
        try:
            if len(parts) != 3 or parts[0] != "TPODS-VALVES":
                raise ValueError
            n = int(parts[2])
            if n < 1:
                raise ValueError
        except ValueError:
            raise DeviceError(f"not a TPODS valve controller: ID? answered {reply!r}") from None
        self.identity = ValveIdentity(parts[0], parts[1], n)
        self.n_channels = n
        return self.identity

    def ping(self) -> None:
        """``PING`` -> ``PONG`` (also feeds the watchdog)."""
        reply = self.command("PING")
        if reply != "PONG":
            raise DeviceError(f"valve controller answered {reply!r} to PING")

    def set_freq(self, hz: float) -> None:
        """PWM frequency, 1-100 Hz."""
        if not (math.isfinite(hz) and 1 <= hz <= 100):
            raise UserError(f"PWM frequency must be 1-100 Hz, got {hz:g}")
        self._expect_ok(f"FREQ {_fmt(hz)}")

    def _check_duty(self, pct: float) -> None:
        lo, hi = self.duty_limits
        if not math.isfinite(pct) or pct < 0 or pct > 100:
            raise UserError(f"duty must be 0-100 %, got {pct}")
        if pct != 0 and not lo <= pct <= hi:
            raise UserError(f"duty {pct:g} % is outside the allowed {lo:g}-{hi:g} % (0 closes)")

    def _channels(self) -> int:
        if self.n_channels is None:
            self.identify()
        return self.n_channels  # type: ignore[return-value]

    def set_duty(self, ch: int, pct: float) -> None:
        """Duty of channel ``ch`` (1-based) in percent; 0 closes it."""
        n = self._channels()
        if not 1 <= ch <= n:
            raise UserError(f"valve channel must be 1-{n}, got {ch}")
        self._check_duty(pct)
        self._expect_ok(f"DUTY {ch} {_fmt(pct)}")

    def set_all(self, duties: Sequence[float]) -> None:
        """Duty of every channel at once (``DUTY*``), percent."""
        n = self._channels()
        duties = [float(d) for d in duties]
        if len(duties) != n:
            raise UserError(f"expected {n} duties, got {len(duties)}")
        for d in duties:
            self._check_duty(d)
        self._expect_ok("DUTY* " + " ".join(_fmt(d) for d in duties))

    def off(self) -> None:
        """Close every valve."""
        self._expect_ok("OFF")

    def watchdog(self, ms: int) -> None:
        """Arm the watchdog: all valves close if no command arrives for ``ms`` (0 disables)."""
        if ms < 0 or int(ms) != ms:
            raise UserError(f"watchdog must be a non-negative whole number of ms, got {ms}")
        self._expect_ok(f"WDT {int(ms)}")

    def state(self) -> tuple[float, ...]:
        """``STATE?``: the duty of every channel, percent."""
        reply = self.command("STATE?")
        parts = reply.split()
        try:
            if not parts or parts[0] != "STATE":
                raise ValueError
            vals = tuple(float(p) for p in parts[1:])
            if self.n_channels is not None and len(vals) != self.n_channels:
                raise ValueError
        except ValueError:
            raise DeviceError(f"valve controller answered {reply!r} to STATE?") from None
        return vals

    def off_confirmed(self, attempts: int = 3) -> tuple[float, ...]:
        """Send OFF and read STATE? until every channel reads 0; DeviceError if it never does.

        Ctrl-C during this call does not interrupt it: the interrupt is re-raised after.
        """
        interrupted: BaseException | None = None
        last_err: Exception | None = None
        state: tuple[float, ...] = ()
        for _ in range(attempts):
            try:
                self.off()
                state = self.state()
                if not any(state):
                    break
            except (KeyboardInterrupt, SystemExit) as exc:  # keep closing, then re-raise
                interrupted = exc
            except DeviceError as exc:
                last_err = exc
        else:
            if interrupted is not None:
                raise interrupted
            raise DeviceError(f"could not confirm that the valves closed "
                              f"({last_err or f'STATE? says {state}'}): CLOSE THE AIR SUPPLY")
        if interrupted is not None:
            raise interrupted
        return state

    @contextlib.contextmanager
    def safe(self, watchdog_ms: int = 500, feed_every_s: float | None = None,
             stall_s: float | None = None) -> Iterator[SafeValves]:
        """Arm the watchdog, feed it while the caller lives, close the valves on exit.

        Args:
            watchdog_ms: controller watchdog; the valves close by themselves this long
                after the host stops talking (crash, kill -9, pulled cable).
            feed_every_s: feeder period (default a quarter of the watchdog).
            stall_s: the feeder stops feeding when the caller has neither sent a
                command nor called ``heartbeat()`` for this long (default the watchdog
                time), so a hung main loop closes the valves too.

        On every exit path OFF is sent and confirmed with STATE?; if that fails a
        DeviceError is raised (chained after any exception already propagating).
        """
        if watchdog_ms <= 0:
            raise UserError("the safe-valves context needs a positive watchdog time")
        guard = SafeValves(self, watchdog_ms, feed_every_s, stall_s)
        guard.start()
        try:
            yield guard
        finally:
            guard.stop()
            guard.final_state = self.off_confirmed()


class SafeValves:
    """Watchdog feeder of :meth:`ValveController.safe` (see there)."""

    def __init__(self, valves: ValveController, watchdog_ms: int,
                 feed_every_s: float | None, stall_s: float | None) -> None:
        self.valves = valves
        self.watchdog_ms = int(watchdog_ms)
        self.feed_every_s = feed_every_s if feed_every_s is not None else watchdog_ms / 4000.0
        self.stall_s = stall_s if stall_s is not None else watchdog_ms / 1000.0
        self._beat = clock.monotonic()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.feeds = 0
        self.feed_error: Exception | None = None
        self.final_state: tuple[float, ...] | None = None

    def heartbeat(self) -> None:
        """Tell the feeder the caller is alive (call at least every ``stall_s``)."""
        self._beat = clock.monotonic()

    def start(self) -> None:
        self.valves.off()
        self.valves.watchdog(self.watchdog_ms)
        self.heartbeat()
        self._thread = threading.Thread(target=self._feed, name="valve-watchdog-feeder", daemon=True)
        self._thread.start()

    def _feed(self) -> None:
        while not self._stop.wait(self.feed_every_s / 2):
            now = clock.monotonic()
            alive = max(self._beat, self.valves.last_caller_t)
            if now - alive > self.stall_s:
                continue  # the caller is stuck: let the watchdog close the valves
            if now - self.valves.last_command_t < self.feed_every_s:
                continue  # recent traffic already fed it
            try:
                reply = self.valves.command("PING", _feeder=True)
                if reply != "PONG":
                    raise DeviceError(f"valve controller answered {reply!r} to PING")
                self.feeds += 1
            except Exception as exc:  # reported by the caller's next command or exit
                self.feed_error = exc

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
