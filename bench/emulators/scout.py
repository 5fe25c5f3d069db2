"""Emulated OHAUS Scout balance weighing the thrust of one nozzle.

The pan reads ``load_g`` (an object on the pan) plus the thrust, in gram-force, of
the nozzle under test of a linked :class:`EmulatedValveController`: the truth
:class:`common.thrust_table.ThrustTable` (default: the paper's Table 2) at that
channel's duty for the number of open valves. The reading follows the truth through
a first-order lag, with Gaussian noise, a slow linear zero drift, occasional
unstable readings and occasional garbage lines, all seeded and configurable.

Commands (case-sensitive, ended by CR LF; a lone CR or LF is accepted too):
``IP`` print now, ``P`` print the display, ``SP`` print at the next stable reading,
``CP`` continuous print, ``xP`` print every x seconds, ``0P`` stop printing, ``Z`` zero,
``T`` tare (both answer ``OK!``), ``PU`` print the unit, ``xU`` set the unit
(1 g, 2 kg, 3 ct, 4 oz, 5 lb; ``OK!``), ``PV`` version; anything else answers ``ES``.
With ``continuous_print=False`` (continuous print disabled in the balance's menu, or a
model without it) ``CP`` and ``xP`` answer ``ES`` and print nothing.

Print content (default: the Scout's ``      12.34 g ?`` and nothing else): ``legend``
prints a legend after the stability field (``"N"``, ``"NET"``, ``"G"``, ``"B/G"``: a
Navigator, Ranger or Defender with a legend), ``print_unit=False`` blanks the unit field
(Defender 5000 "Print Content: Unit OFF"), and ``print_content`` lists the lines of one
print in order: ``"weight"`` (the displayed weight) and ``"tare"`` (the stored tare value
with the legend ``T``, as a Defender or Ranger prints it when tare is in its print content).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from bench.emulators.valves import EmulatedValveController
from common.thrust_table import ThrustTable

UNITS = {1: ("g", 1.0), 2: ("kg", 1e-3), 3: ("ct", 5.0), 4: ("oz", 1 / 28.349523125),
         5: ("lb", 1 / 453.59237)}
"""Unit number (``xU``) -> (symbol, factor from grams)."""

_DECIMALS = {"g": 2, "kg": 5, "ct": 1, "oz": 4, "lb": 5}

GARBAGE = (b"\x00\xff\xfe", b"  12.3", b"#?!", b"\xa5\xa5 g ?", b"1.2.3.4 g")


@dataclass(frozen=True)
class SentLine:
    """One line the balance sent: monotonic time, bytes, kind (weight/garbage/reply)."""

    t: float
    data: bytes
    kind: str


class EmulatedScout:
    """An OHAUS Scout whose pan feels the thrust of one nozzle.

    Args:
        valves: linked valve emulator (None: only ``load_g`` is on the pan).
        table: truth thrust table (default the paper's Table 2).
        nozzle_under_test: channel (1-based) whose nozzle pushes on the pan.
        load_g: static mass on the pan, grams.
        lag_s: time constant of the first-order lag, seconds (0: none).
        noise_g: standard deviation of the Gaussian reading noise, grams.
        drift_g_per_s: zero drift rate, grams per second.
        unstable_prob: probability that a reading is flagged unstable at random
            (readings are also unstable while settling by more than ``stable_band_g``).
        garbage_prob: probability that a printed line is replaced by garbage.
        print_rate_hz: continuous print rate.
        continuous_print: False: ``CP`` and ``xP`` are refused with ``ES``.
        legend, print_unit, print_content: what a print holds (module docstring).
        stable_band_g: a reading is unstable while |lagged - target| exceeds this.
        seed: random seed.
        clock: monotonic clock, seconds.
    """

    def __init__(self, valves: EmulatedValveController | None = None,
                 table: ThrustTable | None = None, nozzle_under_test: int = 1,
                 load_g: float = 0.0, lag_s: float = 0.3, noise_g: float = 0.2,
                 drift_g_per_s: float = 0.003, unstable_prob: float = 0.03,
                 garbage_prob: float = 0.01, print_rate_hz: float = 10.0,
                 stable_band_g: float = 1.0, seed: int | None = 0,
                 version: str = "SCOUT STX EMU 1.00", continuous_print: bool = True,
                 legend: str | None = None, print_unit: bool = True,
                 print_content: tuple[str, ...] = ("weight",),
                 clock: Callable[[], float] = time.monotonic) -> None:
        if not print_content or set(print_content) - {"weight", "tare"}:
            raise ValueError(f"print_content items are 'weight' and 'tare', got {print_content!r}")
        self.valves = valves
        self.table = table if table is not None else ThrustTable.default()
        self.nozzle_under_test = nozzle_under_test
        self.load_g = load_g
        self.lag_s = lag_s
        self.noise_g = noise_g
        self.drift_g_per_s = drift_g_per_s
        self.unstable_prob = unstable_prob
        self.garbage_prob = garbage_prob
        self.print_rate_hz = print_rate_hz
        self.continuous_print = continuous_print
        self.legend = legend
        self.print_unit = print_unit
        self.print_content = tuple(print_content)
        self.stable_band_g = stable_band_g
        self.version = version
        self.clock = clock
        self.rng = np.random.default_rng(seed)
        self.silent = False
        """When True the balance ignores commands and prints nothing (a lost balance)."""
        self.unit_no = 1
        self.zero_offset_g = 0.0
        self.sent: list[SentLine] = []
        self._lock = threading.RLock()
        self._t0 = clock()
        self._t_state = self._t0
        self._thrust_state = self._thrust_target()
        self._buf = b""
        self._period: float | None = None  # continuous / interval print period
        self._next_print: float | None = None
        self._pending_sp = 0
        if valves is not None:
            valves.add_listener(self._on_valves)

    # ------------------------------------------------------------- physics
    def _thrust_target(self, duties: tuple[float, ...] | None = None) -> float:
        if self.valves is None:
            return 0.0
        d = self.valves.duties if duties is None else duties
        k = sum(1 for x in d if x > 0)
        duty = d[self.nozzle_under_test - 1]
        if duty <= 0 or k not in self.table.coefficients:
            return 0.0
        return max(0.0, float(self.table.per_nozzle(duty, k)))

    def _advance(self, now: float) -> None:
        dt = now - self._t_state
        if dt <= 0:
            return
        target = self._thrust_target()
        if self.lag_s > 0:
            self._thrust_state = target + (self._thrust_state - target) * math.exp(-dt / self.lag_s)
        else:
            self._thrust_state = target
        self._t_state = now

    def _on_valves(self, now: float, duties: tuple[float, ...]) -> None:
        with self._lock:
            self._advance(now)  # up to the change, with the old target

    def gross_g(self, now: float | None = None) -> float:
        """Noise-free gross reading in grams at ``now`` (lagged thrust + load + drift)."""
        now = self.clock() if now is None else now
        with self._lock:
            self._advance(now)
            return self.load_g + self._thrust_state + self.drift_g_per_s * (now - self._t0)

    def truth_thrust_gf(self) -> float:
        """Steady thrust of the nozzle under test for the current duties, gram-force."""
        return self._thrust_target()

    def _measure(self, now: float) -> tuple[float, bool]:
        g = self.gross_g(now)
        settling = abs(self._thrust_state - self._thrust_target()) > self.stable_band_g
        value = g - self.zero_offset_g + self.noise_g * float(self.rng.standard_normal())
        unstable = settling or bool(self.rng.random() < self.unstable_prob)
        return value, not unstable

    def format_reading(self, value_g: float, stable: bool, legend: str | None = None) -> bytes:
        """One weight line: ``legend`` (default ``self.legend``) after the stability field."""
        legend = self.legend if legend is None else legend
        unit, factor = UNITS[self.unit_no]
        dec = _DECIMALS[unit]
        field = unit if self.print_unit else " " * max(len(unit), 2)
        text = f"{value_g * factor:10.{dec}f} {field}"
        if legend:
            text += f" {' ' if stable else '?'} {legend}"
        elif not stable:
            text += " ?"
        return text.encode() + b"\r\n"

    def print_lines(self, value_g: float, stable: bool) -> bytes:
        """The lines of one print, in ``print_content`` order."""
        return b"".join(self.format_reading(value_g, stable) if item == "weight"
                        else self.format_reading(self.zero_offset_g, True, "T")
                        for item in self.print_content)

    def _emit(self, now: float, data: bytes, kind: str) -> bytes:
        self.sent.append(SentLine(now, data, kind))
        return data

    def _weight_line(self, now: float, allow_garbage: bool = True) -> bytes:
        if allow_garbage and self.garbage_prob > 0 and self.rng.random() < self.garbage_prob:
            junk = GARBAGE[int(self.rng.integers(len(GARBAGE)))]
            return self._emit(now, junk + b"\r\n", "garbage")
        value, stable = self._measure(now)
        return self._emit(now, self.print_lines(value, stable), "weight")

    # ------------------------------------------------------------ protocol
    def command(self, cmd: str, now: float | None = None) -> bytes:
        """Handle one command (without CR LF); return the reply bytes (maybe empty)."""
        now = self.clock() if now is None else now
        with self._lock:
            if self.silent:
                return b""
            if cmd in ("IP", "P"):
                return self._weight_line(now)
            if cmd == "SP":
                value, stable = self._measure(now)
                if stable:
                    return self._emit(now, self.print_lines(value, True), "weight")
                self._pending_sp += 1
                return b""
            if not self.continuous_print and (cmd == "CP" or (
                    len(cmd) >= 2 and cmd.endswith("P") and cmd[:-1].isdigit() and cmd != "0P")):
                return self._emit(now, b"ES\r\n", "reply")
            if cmd == "CP":
                self._period = 1.0 / self.print_rate_hz
                self._next_print = now
                return b""
            if cmd == "0P":
                self._period = self._next_print = None
                return b""
            if len(cmd) >= 2 and cmd.endswith("P") and cmd[:-1].isdigit():
                self._period = float(int(cmd[:-1]))
                self._next_print = now
                return b""
            if cmd in ("Z", "T"):
                self.zero_offset_g = self.gross_g(now)
                return self._emit(now, b"OK!\r\n", "reply")
            if cmd == "PU":
                return self._emit(now, f"{UNITS[self.unit_no][0]}\r\n".encode(), "reply")
            if cmd.endswith("U") and cmd[:-1].isdigit() and int(cmd[:-1]) in UNITS:
                self.unit_no = int(cmd[:-1])
                return self._emit(now, b"OK!\r\n", "reply")
            if cmd == "PV":
                return self._emit(now, self.version.encode() + b"\r\n", "reply")
            return self._emit(now, b"ES\r\n", "reply")

    def receive(self, data: bytes, now: float) -> bytes:
        self._buf += data.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
        out = []
        while b"\n" in self._buf:
            raw, self._buf = self._buf.split(b"\n", 1)
            cmd = raw.decode("ascii", "replace").strip()
            if cmd:
                out.append(self.command(cmd, now))
        if len(self._buf) > 64:
            self._buf = b""
        return b"".join(out)

    def tick(self, now: float) -> tuple[bytes, float | None]:
        with self._lock:
            out = []
            if self.silent:
                return b"", None
            if self._pending_sp:
                value, stable = self._measure(now)
                if stable:
                    for _ in range(self._pending_sp):
                        out.append(self._emit(now, self.print_lines(value, True), "weight"))
                    self._pending_sp = 0
            if self._next_print is not None and now >= self._next_print:
                out.append(self._weight_line(now))
                self._next_print += self._period
                if self._next_print < now:  # fell behind (loaded machine): skip, don't burst
                    self._next_print = now + self._period
            nxt = self._next_print
            if self._pending_sp:
                nxt = now + 0.02 if nxt is None else min(nxt, now + 0.02)
            return b"".join(out), nxt
