"""Ranges of the values that describe a vehicle's thrust: one validator for every door they
enter by (vehicle.toml, ``--at``, ``--fixed``, ``--initial``), so a typo or a unit mistake
is refused in one line that names the unit that would make it plausible.

- an on/off valve's force, :data:`FORCE_RANGE_N` (an air-table cold-gas thruster gives
  millinewtons to a few newtons), and its stated sigma, at most the force itself;
- a valve dead time or rise time, :data:`TIME_RANGE_S` (a solenoid valve switches in
  milliseconds; seconds would be a clock or a unit mistake);
- a supply's drop per other open valve, 0 <= drop < 1/(n-1) (forces stay positive with
  every valve open);
- a mass or an Izz: positive and finite (zero is refused, never read as "not given").
"""

from __future__ import annotations

import math

from common.errors import UserError

FORCE_RANGE_N = (1e-3, 50.0)
"""Refused outside: no air-table thruster gives less than a millinewton or more than 50 N."""
TYPICAL_FORCE_N = (5e-3, 5.0)
"""Warned outside, for a force measured rather than typed (a load cell's): cold-gas
thrusters on air tables give 5 mN to 5 N; grams read as newtons give tens of newtons."""
TIME_RANGE_S = (0.0, 2.0)

_FORCE_UNITS = (("mN", 1e-3), ("gf", 9.80665e-3), ("kgf", 9.80665), ("lbf", 4.4482216))


def _finite(value: float, what: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise UserError(f"{what} must be a number, got {value!r}") from None
    if not math.isfinite(v):
        raise UserError(f"{what} must be finite, got {value!r}")
    return v


def check_force_n(value: float, what: str) -> float:
    """An on/off valve's force in N within :data:`FORCE_RANGE_N`, else UserError naming the
    units that would put it there."""
    v = _finite(value, what)
    lo, hi = FORCE_RANGE_N
    if lo <= v <= hi:
        return v
    fits = [f"{v * k:.4g} N if it is in {u}" for u, k in _FORCE_UNITS if lo <= v * k <= hi]
    hint = f" ({'; '.join(fits)})" if fits else ""
    raise UserError(f"{what} = {v:g} N is outside {lo:g}-{hi:g} N (an air-table thruster)"
                    f"{hint}")


def check_force_sigma_n(sigma: float, force: float, what: str) -> float:
    """A force's stated sigma: 0 <= sigma <= the force (a larger one states no force)."""
    s = _finite(sigma, what)
    if not 0.0 <= s <= force:
        raise UserError(f"{what} = {s:g} N must lie in 0..force_n ({force:g} N): a sigma "
                        "larger than the force states nothing about it")
    return s


def check_time_s(value: float, what: str) -> float:
    """A valve dead time or rise time in s within :data:`TIME_RANGE_S`."""
    v = _finite(value, what)
    lo, hi = TIME_RANGE_S
    if lo <= v <= hi:
        return v
    hint = f" ({v / 1000:g} s if it is in ms)" if lo <= v / 1000 <= hi else ""
    raise UserError(f"{what} = {v:g} s is outside {lo:g}-{hi:g} s (a valve switches in "
                    f"milliseconds){hint}")


def check_drop(value: float, n_valves: int, what: str) -> float:
    """A drop per other open valve: 0 <= drop < 1/(n-1) for n valves on the supply."""
    v = _finite(value, what)
    limit = 1.0 / max(n_valves - 1, 1)
    if not 0.0 <= v < limit:
        raise UserError(f"{what} = {v:g} must be >= 0 and < 1/(n-1) = {limit:.4g} with n = "
                        f"{n_valves} valves on the supply (every force stays positive)")
    return v


def check_positive(value: float, what: str) -> float:
    """A mass or an Izz: positive and finite (0 is a value, and not a possible one)."""
    v = _finite(value, what)
    if not v > 0:
        raise UserError(f"{what} must be positive, got {v:g}")
    return v


LOADCELL_UNITS_N = {"g": 9.80665e-3, "gf": 9.80665e-3, "kg": 9.80665, "kgf": 9.80665, "N": 1.0,
                    "mN": 1e-3}
"""Newtons per unit of a load-cell log's force column (a mass reading is gram- or
kilogram-force)."""


def loadcell_force_warning(force_n: float, unit: str | None, what: str) -> str | None:
    """A warning when a force measured on a load cell lies outside :data:`TYPICAL_FORCE_N`,
    naming the column unit (``--force-unit``) that would put it inside, or None."""
    lo, hi = TYPICAL_FORCE_N
    if not math.isfinite(force_n) or lo <= abs(force_n) <= hi:
        return None
    fits = []
    if unit in LOADCELL_UNITS_N:
        reading = force_n / LOADCELL_UNITS_N[unit]
        fits = [f"--force-unit {u}: {reading * k:.4g} N" for u, k in LOADCELL_UNITS_N.items()
                if u != unit and lo <= abs(reading * k) <= hi and u not in ("gf", "kgf")]
    hint = f"; with {' or '.join(fits)}" if fits else ""
    return (f"{what}: {force_n:.4g} N is outside {lo:g}-{hi:g} N (an air-table cold-gas thruster): "
            f"the log's force column is read as {unit}{hint}")
