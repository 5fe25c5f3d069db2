"""Mass from a balance: N stable readings, mean, spread and a GUM uncertainty.

Pure computation in :func:`mass_from_readings`; :func:`take_readings` pulls stable
readings from any callable (the OHAUS driver's ``read``, an emulator, a test stub);
:func:`parse_readings_text` reads hand-written readings.

Uncertainty (GUM, JCGM 100:2008), all in kg:

- Type A, repeatability: u_A = s / sqrt(N), s the sample standard deviation of the
  N readings (N >= 2).
- Type B, the balance's stated accuracy +-a taken as a rectangular distribution:
  u_B = a / sqrt(3). Optional display resolution d: u_res = d / (2 sqrt(3)).
- Combined: u_c = sqrt(u_A^2 + u_B^2 + u_res^2); expanded U = k u_c (k = 2, ~95 %).

A mean reading within the accuracy of zero (an empty pan) is refused; a mass outside what an
air-table body weighs is flagged in ``warnings`` (the rules of :mod:`common.plausible`).

Assumptions: the readings are independent and of the same unchanged load; the
accuracy bound is the manufacturer's for the range used, not a calibration
certificate's (which would give a normal uncertainty instead).
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from common.errors import DeviceError, UserError
from common.plausible import balance_mass_warnings, check_balance_reading

UNIT_TO_KG = {"g": 1e-3, "kg": 1.0, "mg": 1e-6, "lb": 0.45359237, "oz": 0.028349523125}


def to_kg(value: float, unit: str) -> float:
    """Convert a balance value to kg (units g, kg, mg, lb, oz; case-insensitive)."""
    u = unit.strip().lower()
    if u not in UNIT_TO_KG:
        raise UserError(f"unknown mass unit {unit!r} (known: {', '.join(UNIT_TO_KG)})")
    return float(value) * UNIT_TO_KG[u]


@dataclass
class MassResult:
    """Mass estimate in kg with its GUM budget."""

    mass_kg: float
    std_kg: float
    u_typeA_kg: float
    u_typeB_kg: float
    u_resolution_kg: float
    u_combined_kg: float
    n_readings: int
    coverage_k: float = 2.0
    readings_kg: list[float] = field(default_factory=list)
    skipped: int = 0
    assumptions: str = ("readings independent, same load; accuracy bound +-a as a rectangular "
                        "distribution (a/sqrt(3)); repeatability s/sqrt(N)")
    warnings: list[str] = field(default_factory=list)
    """A mass implausible for an air-table body (:func:`common.plausible.balance_mass_warnings`)."""

    @property
    def expanded_kg(self) -> float:
        return self.coverage_k * self.u_combined_kg

    def to_dict(self) -> dict[str, Any]:
        d = {k: getattr(self, k) for k in (
            "mass_kg", "std_kg", "u_typeA_kg", "u_typeB_kg", "u_resolution_kg", "u_combined_kg",
            "n_readings", "coverage_k", "readings_kg", "skipped", "assumptions")}
        if self.warnings:
            d["warnings"] = list(self.warnings)
        d["expanded_kg"] = self.expanded_kg
        d["mass_sigma_kg"] = self.u_combined_kg
        return d


def mass_from_readings(readings_kg: Sequence[float], accuracy_kg: float, resolution_kg: float = 0.0,
                       coverage_k: float = 2.0, skipped: int = 0, unit: str | None = None
                       ) -> MassResult:
    """Mean, sample std and combined standard uncertainty of N readings (kg).

    Args:
        readings_kg: (N,) stable readings, kg, N >= 2.
        accuracy_kg: half-width a of the balance's stated accuracy (+-a), kg, >= 0.
        resolution_kg: display resolution d, kg (0: already inside the accuracy).
        unit: the unit the readings were given in, named by a mass warning.
    """
    x = np.asarray(readings_kg, dtype=float)
    if x.ndim != 1 or x.size < 2:
        raise UserError(f"need at least 2 readings for a repeatability estimate, got {x.size}")
    if not np.all(np.isfinite(x)):
        raise UserError("readings must be finite numbers")
    if np.any(x <= 0):
        raise UserError("readings must be positive (is the pan loaded and the balance zeroed?)")
    if accuracy_kg < 0 or resolution_kg < 0 or not math.isfinite(accuracy_kg + resolution_kg):
        raise UserError("accuracy and resolution must be non-negative")
    check_balance_reading(float(x.mean()), accuracy_kg)  # an empty pan
    s = float(x.std(ddof=1))
    u_a = s / math.sqrt(x.size)
    u_b = accuracy_kg / math.sqrt(3.0)
    u_r = resolution_kg / (2.0 * math.sqrt(3.0))
    return MassResult(float(x.mean()), s, u_a, u_b, u_r, math.sqrt(u_a**2 + u_b**2 + u_r**2),
                      int(x.size), coverage_k, [float(v) for v in x], skipped,
                      warnings=balance_mass_warnings(float(x.mean()), unit))


_LINE = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([A-Za-z]*)\s*(\?)?\s*$")


_DECIMAL_COMMA = re.compile(r"(\d+),(\d+)")


def parse_readings_text(text: str, default_unit: str = "g", source: str = "readings"
                        ) -> tuple[list[float], int]:
    """Readings written by hand or logged from a balance, one per line, to kg.

    A line is a number, optionally a unit (g, kg, mg, lb, oz) and a trailing ``?``
    (OHAUS: unstable, skipped and counted); blank lines and ``#`` comments are
    ignored; commas followed by a space (or at a line's end) also separate readings. A
    comma directly between two digits (``720,1``: a decimal comma, or two readings?) is
    refused as ambiguous; a UTF-8 byte order mark is skipped. Returns
    (readings_kg, unstable_skipped). Anything else is refused with the line number.
    """
    vals: list[float] = []
    unstable = 0
    text = text.removeprefix("\ufeff")
    for i, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        amb = _DECIMAL_COMMA.search(line)
        if amb:
            raise UserError(f"{source}: line {i}: {line!r}: a decimal comma? write "
                            f"{amb.group(1)}.{amb.group(2)} (readings are separated by a comma "
                            "and a space, or one per line)")
        for part in (p for p in line.split(",") if p.strip()):
            m = _LINE.match(part)
            if not m:
                raise UserError(f"{source}: line {i}: not a reading ({part.strip()!r})")
            if m.group(3):
                unstable += 1
                continue
            vals.append(to_kg(float(m.group(1)), m.group(2) or default_unit))
    return vals, unstable


def take_readings(read: Callable[[], Any], n: int, max_attempts: int | None = None,
                  progress: Callable[[int], None] | None = None,
                  fatal: tuple[type[BaseException], ...] = ()) -> tuple[list[float], int]:
    """Collect ``n`` stable readings (kg) from ``read()``.

    ``read()`` returns an object with ``value``, ``unit`` and ``stable`` attributes
    (the OHAUS driver's Reading) or a (value, unit, stable) tuple. Unstable or
    unparseable readings (DeviceError, ValueError) are counted and skipped; after
    ``max_attempts`` (default 3 n) calls without n stable readings, DeviceError.
    Exceptions of a type in ``fatal`` are raised at once (a balance that prints only
    tare or total lines will not start printing the load by being asked again).
    Returns (readings_kg, skipped).
    """
    if n < 2:
        raise UserError(f"--readings must be at least 2, got {n}")
    max_attempts = max_attempts or 3 * n
    got: list[float] = []
    skipped = 0
    for _ in range(max_attempts):
        if len(got) >= n:
            break
        try:
            r = read()
            if isinstance(r, tuple):
                value, unit, stable = r
                kg = to_kg(float(value), str(unit))
            else:
                stable = r.stable
                grams = getattr(r, "grams", None)  # the OHAUS Reading knows its units
                kg = grams * 1e-3 if grams is not None else to_kg(float(r.value), str(r.unit))
        except fatal:
            raise
        except (DeviceError, ValueError, TypeError, UserError):
            skipped += 1
            continue
        if not stable or not math.isfinite(kg):
            skipped += 1
            continue
        got.append(kg)
        if progress:
            progress(1)
    if len(got) < n:
        raise DeviceError(f"the balance gave {len(got)} stable readings out of {n} wanted "
                          f"({skipped} unstable or unreadable); is the load steady?")
    return got, skipped


def readings_from_iterable(it: Iterable[Any]) -> Callable[[], Any]:
    """Adapt an iterable of readings to the ``read()`` callable take_readings wants."""
    iterator = iter(it)

    def read():
        try:
            return next(iterator)
        except StopIteration:
            raise DeviceError("no more readings") from None

    return read
