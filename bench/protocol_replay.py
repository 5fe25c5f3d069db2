"""pyserial URL handler ``replay://PATH``: a serial transcript (:mod:`bench.capture`) as a device.

``serial.serial_for_url("replay:///abs/run/valves.serial.jsonl")`` (or a relative
``replay://runs/x/valves.serial.jsonl``) opens a port that answers as the recorded device
did, so the drivers run unchanged against a recording. Importing :mod:`bench.serial_link`
registers the handler (``serial.protocol_handler_packages``).

Modes (``?mode=``):

``strict`` (default)
    The host must send the recorded bytes in order. Each recorded ``rx`` chunk is
    delivered only after every ``tx`` recorded before it was sent, and as one read
    (chunk boundaries are kept); a chunk recorded as ``ready`` (already waiting when the
    host asked) is readable at once, the others at their recorded time. A difference raises :class:`ReplayMismatch` (a
    ``SerialException``: the drivers report it as a write failure) naming the first
    differing exchange: its number (the n-th ``tx`` of the transcript), its recorded time,
    the expected and the actual bytes. After it the port only answers writes found later in
    the recording (so a driver's closing ``OFF`` and ``STATE?`` get their recorded
    replies and the first error is the one reported); ``mismatch`` keeps it. Recorded replies
    the host did not read before its next command are dropped, as a real port's input
    buffer would be. The header's ``keepalive`` command (the valve watchdog's ``PING``,
    sent from a thread whenever the scheduler runs it) is not held to its recorded places:
    an extra one is answered with the recorded reply, a recorded one the host did not send
    is skipped (counted in ``keepalives_answered`` / ``keepalives_skipped``).

    Time is virtual (``clock=virtual``, the default): while the port is open the bench's
    clock (:mod:`bench.clock`) is the recording's, shared by every replayed port. A read
    returns a recorded chunk with the clock set to the time it was read when recorded; a
    read that times out moves the clock by its timeout. A replayed session therefore sees
    the recorded times bit for bit and takes no longer than its computing. With
    ``clock=real`` the chunks are delivered no earlier than their recorded time after
    opening, on the system clock.

``paced``
    Lenient: every ``rx`` chunk becomes readable at its recorded time after opening,
    whatever the host sends (written bytes are accepted and counted in ``tx_bytes``);
    time is real.

Timeouts behave like a port: ``read(n)`` returns what is there when the timeout ends
(``b""`` if nothing), ``timeout=0`` never waits.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

from serial.serialutil import PortNotOpenError, SerialBase, SerialException

from bench import clock as bench_clock
from bench.capture import read_transcript
from common.errors import UserError


class ReplayMismatch(SerialException):
    """The host sent bytes other than the recorded ones (strict replay)."""


class VirtualClock:
    """The recording's time line (see :mod:`bench.clock`); advanced by the replayed ports."""

    def __init__(self, t: float) -> None:
        self.t = t
        self._lock = threading.Lock()

    def monotonic(self) -> float:
        return self.t

    def advance_to(self, t: float) -> None:
        with self._lock:
            if t > self.t:
                self.t = t

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            self.advance_to(self.t + seconds)


def _show(data: bytes, limit: int = 80) -> str:
    text = repr(bytes(data[:limit]))
    return text + ("..." if len(data) > limit else "")


class Serial(SerialBase):
    """A recorded device (see the module docstring)."""

    def open(self) -> None:
        if self._port is None:
            raise SerialException("Port must be configured before it can be used.")
        if self.is_open:
            raise SerialException("Port is already open.")
        self.from_url(self.portstr)
        try:
            self.header, events = read_transcript(self.path)
        except UserError as exc:
            raise SerialException(str(exc)) from None
        t_open = float(self.header.get("t_open_monotonic") or 0.0)
        # recorded times on the host's monotonic time line (shared by the ports of one session)
        self._events = [(t_open + t, d, data, ready) for t, d, data, ready, _ in events]
        self._t_call = [None if tc is None else t_open + tc for *_, tc in events]
        ka = self.header.get("keepalive")
        self.keepalive = ka.encode("latin-1") if ka else None
        self._ka_reply = self._keepalive_reply()
        self._lock = threading.RLock()
        self._pos = 0          # next event
        self._off = 0          # bytes of events[_pos] already consumed
        self._inject = b""     # replies to keepalives that were not recorded there
        self._ka_rx = False    # events[_pos] is the reply to a matched keepalive
        self.exchanges = 0     # tx chunks matched
        self.keepalives_answered = 0
        self.keepalives_skipped = 0
        self.rx_dropped = 0    # recorded reply bytes the host never read
        self.tx_bytes = 0
        self.mismatch: ReplayMismatch | None = None
        self._clock: VirtualClock | None = None
        self._t0_real = time.monotonic() - t_open
        if self.virtual:
            installed = bench_clock.install(VirtualClock(t_open))
            if not isinstance(installed, VirtualClock):
                bench_clock.release()
                raise SerialException("another clock is installed; cannot replay on virtual time")
            self._clock = installed
            installed.advance_to(t_open)
        self.is_open = True

    def from_url(self, url: str) -> None:
        parts = urlsplit(url)
        if parts.scheme.lower() != "replay":
            raise SerialException(f"expected replay://PATH[?mode=strict|paced], got {url!r}")
        path = parts.netloc + parts.path
        if not path:
            raise SerialException(f"{url!r}: no transcript path (replay:///abs/path.jsonl)")
        self.path = Path(path)
        opts = parse_qs(parts.query, keep_blank_values=True)
        unknown = set(opts) - {"mode", "clock"}
        if unknown:
            raise SerialException(f"{url!r}: unknown option {sorted(unknown)[0]!r} (mode, clock)")
        self.mode = opts.get("mode", ["strict"])[-1]
        if self.mode not in ("strict", "paced"):
            raise SerialException(f"{url!r}: mode must be strict or paced, not {self.mode!r}")
        clk = opts.get("clock", ["virtual" if self.mode == "strict" else "real"])[-1]
        if clk not in ("virtual", "real") or (self.mode == "paced" and clk == "virtual"):
            raise SerialException(f"{url!r}: clock must be virtual or real (paced: real), not {clk!r}")
        self.virtual = clk == "virtual"

    def _keepalive_reply(self) -> bytes:
        """The recorded reply to the first recorded keepalive (its rx chunks up to the next tx)."""
        if not self.keepalive:
            return b""
        ev = self._events
        for i, (_, d, data, _r) in enumerate(ev):
            if d == "tx" and data == self.keepalive:
                out = b""
                for _, d2, data2, _r2 in ev[i + 1:]:
                    if d2 == "tx":
                        break
                    out += data2
                return out
        return b""

    def close(self) -> None:
        if self.is_open:
            self.is_open = False
            if self._clock is not None:
                self._clock = None
                bench_clock.release()

    def _reconfigure_port(self) -> None:
        pass

    # ------------------------------------------------------------------ time
    def _now(self) -> float:
        if self._clock is not None:
            return self._clock.t
        return time.monotonic() - self._t0_real

    def _wait_until(self, t: float) -> None:
        if self._clock is not None:
            self._clock.advance_to(t)
            return
        while (dt := t - self._now()) > 0:
            time.sleep(min(dt, 0.005))

    # ------------------------------------------------------------------ reading
    def _due_at(self) -> float | None:
        """Paced: when the next chunk can be read (None: the recording is over)."""
        self._skip_tx()
        if self._pos >= len(self._events):
            return None
        return self._events[self._pos][0]

    def _skip_tx(self) -> None:
        ev = self._events
        while self._pos < len(ev) and (ev[self._pos][1] == "tx" or not ev[self._pos][2]):
            self._pos += 1
            self._off = 0

    def _consume(self, n: int) -> None:
        """``n`` more bytes of the current event read: on to the next event once all of it
        is (a keepalive's reply ends where the host writes again)."""
        ev = self._events
        self._off += n
        if self._off >= len(ev[self._pos][2]):
            self._pos += 1
            self._off = 0
            if self._ka_rx and (self._pos >= len(ev) or ev[self._pos][1] == "tx"):
                self._ka_rx = False

    def _take(self, size: int) -> bytes:
        """Paced: the bytes due now, up to ``size``."""
        out = b""
        ev = self._events
        now = self._now()
        while len(out) < size and self._pos < len(ev):
            t, d, data, ready = ev[self._pos]
            if d != "rx" or t > now:
                break
            piece = data[self._off:self._off + size - len(out)]
            out += piece
            self._consume(len(piece))
            self._skip_tx()
        return out

    @property
    def in_waiting(self) -> int:
        if not self.is_open:
            raise PortNotOpenError()
        with self._lock:
            if self._inject:
                return len(self._inject)
            ev = self._events
            if self.mode == "strict":
                if self._pos >= len(ev):
                    return 0
                t, d, data, ready = ev[self._pos]
                if d != "rx" or not data:
                    return 0
                if self._off or ready or self._ka_rx or (not self.virtual and t <= self._now()):
                    return len(data) - self._off
                return 0
            n, now, off = 0, self._now(), self._off
            for t, d, data, _ready in ev[self._pos:]:
                if t > now:
                    break
                if d == "rx":
                    n += len(data) - off
                off = 0
            return n

    def read(self, size: int = 1) -> bytes:
        if not self.is_open:
            raise PortNotOpenError()
        if size <= 0:
            return b""
        timeout = self._timeout
        with self._lock:
            if self._inject:
                out, self._inject = self._inject[:size], self._inject[size:]
                return out
            if self.mode == "strict":
                return self._read_strict(size, timeout)
            deadline = None if timeout is None else self._now() + timeout
            while True:
                due = self._due_at()
                if due is not None and due <= self._now():
                    out = self._take(size)
                    if out:
                        return out
                if due is not None and (deadline is None or due <= deadline):
                    self._wait_until(due)
                    continue
                if deadline is None:
                    time.sleep(0.005)
                    continue
                self._wait_until(deadline)
                return b""

    def _later(self, t: float, t_call: float | None, timeout: float) -> bool:
        """Whether the recorded read (issued at ``t_call``, returning at ``t``) is a later
        one than the read the host is making now, which ends at now + ``timeout``."""
        end = self._now() + timeout
        return (t_call if t_call is not None else t) > end

    def _read_strict(self, size: int, timeout: float | None) -> bytes:
        """The next recorded read: its bytes (``b""`` for a recorded timeout), at its time."""
        ev = self._events
        if self._pos >= len(ev) or ev[self._pos][1] != "rx":
            # the host reads where the recording has it send (or the recording ended)
            if timeout is None:
                timeout = 0.0 if self._clock is not None else 3600.0
            self._wait_until(self._now() + timeout)
            return b""
        t, _, data, ready = ev[self._pos]
        if not self._ka_rx:
            if ready or self._off:
                if self._clock is not None:
                    self._clock.advance_to(t)
            elif timeout is not None and self._later(t, self._t_call[self._pos], timeout):
                self._wait_until(self._now() + timeout)  # not this read: a timeout, as on a port
                return b""
            else:
                self._wait_until(t)
        out = data[self._off:self._off + size]
        self._consume(len(out))
        return out

    # ------------------------------------------------------------------ writing
    def write(self, data: bytes) -> int:
        if not self.is_open:
            raise PortNotOpenError()
        data = bytes(data)
        with self._lock:
            self.tx_bytes += len(data)
            if self.mode == "paced":
                return len(data)
            if self.mismatch is not None:
                self._resync(data)
            else:
                self._match(data)
        return len(data)

    def _match(self, data: bytes) -> None:
        ev, ka = self._events, self.keepalive
        rest = data
        while rest:
            if self._pos < len(ev) and ev[self._pos][1] == "rx":
                # recorded replies the host never read: gone, like a flushed input buffer
                while self._pos < len(ev) and ev[self._pos][1] == "rx":
                    self.rx_dropped += len(ev[self._pos][2]) - self._off
                    self._pos += 1
                    self._off = 0
                self._ka_rx = False
            if self._pos >= len(ev):
                if ka and rest.startswith(ka):
                    self._answer_keepalive()
                    rest = rest[len(ka):]
                    continue
                self._fail(f"the recording ends after exchange {self.exchanges}; the host sent "
                           f"{_show(rest)}")
            t, _, expected, _ready = ev[self._pos]
            if self._off == 0 and ka:
                if rest.startswith(ka) and expected != ka:
                    self._answer_keepalive()
                    rest = rest[len(ka):]
                    continue
                if expected == ka and not rest.startswith(ka):
                    self.keepalives_skipped += 1
                    self._pos += 1
                    while self._pos < len(ev) and ev[self._pos][1] == "rx":
                        self._pos += 1
                    continue
            want = expected[self._off:]
            n = min(len(want), len(rest))
            if rest[:n] != want[:n]:
                t_rel = t - float(self.header.get("t_open_monotonic") or 0.0)
                self._fail(f"exchange {self.exchanges + 1} (recorded at t={t_rel:.6f} s) differs: "
                           f"the recording has {_show(expected)}, the host sent {_show(data)}")
            self._off += n
            rest = rest[n:]
            if self._off >= len(expected):
                self._pos += 1
                self._off = 0
                self.exchanges += 1
                is_ka = bool(ka) and expected == ka
                self._ka_rx = is_ka
                if not is_ka and self._clock is not None:
                    self._clock.advance_to(t)

    def _resync(self, data: bytes) -> None:
        """After a mismatch: continue at the next recorded write of exactly ``data`` (the
        drivers' closing OFF and STATE? get their recorded replies), else fail again."""
        ev = self._events
        for j in range(self._pos, len(ev)):
            if ev[j][1] == "tx" and ev[j][2] == data:
                self._pos, self._off, self._inject = j + 1, 0, b""
                self._ka_rx = bool(self.keepalive) and data == self.keepalive
                if self._clock is not None and not self._ka_rx:
                    self._clock.advance_to(ev[j][0])
                return
        if self.keepalive and data == self.keepalive:
            self._answer_keepalive()
            return
        raise ReplayMismatch(str(self.mismatch))

    def _answer_keepalive(self) -> None:
        self.keepalives_answered += 1
        self._inject += self._ka_reply

    def _fail(self, what: str) -> None:
        device = self.header.get("device") or "device"
        self.mismatch = ReplayMismatch(f"strict replay of {self.path.name} ({device}): {what}")
        raise self.mismatch

    # ------------------------------------------------------------------ the rest of a port
    def reset_input_buffer(self) -> None:
        if not self.is_open:
            raise PortNotOpenError()
        with self._lock:
            self._inject = b""  # recorded chunks were read after the host's reset: kept

    def reset_output_buffer(self) -> None:
        if not self.is_open:
            raise PortNotOpenError()

    def flush(self) -> None:
        pass

    # nothing waits to go out; the modem lines of a replayed link: ready, no ring
    out_waiting = 0
    cts = dsr = cd = True
    ri = False

    def _update_rts_state(self) -> None:
        pass

    def _update_dtr_state(self) -> None:
        pass

    def _update_break_state(self) -> None:
        pass

    @property
    def remaining(self) -> int:
        """Recorded chunks not consumed (the host stopped earlier than the recording)."""
        return len(self._events) - self._pos
