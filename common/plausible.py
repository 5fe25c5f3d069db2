"""Plausibility rules, one per physical quantity, shared by every command that takes it.

A value outside what a lab day on an air table can produce is a typo, a unit mistake or a
damaged file; each rule here says so in one line. Two strengths:

- *impossible* values are refused: the ``check_*`` functions raise :class:`UserError`
  (the CLI prints ``tpods: error: ...``, exit 2) naming the file and line, or the option;
- *possible but suspicious* values are flagged: the ``*_problem`` / ``*_warnings``
  functions return the text of a warning ('' or [] when plausible), which the caller
  prints as ``tpods: warning: ...`` (or stores in its result's ``warnings``).

The quantities and their ranges:

- a body's mass, :data:`BODY_MASS_RANGE_KG` (warn), and its radius of gyration
  ``sqrt(Izz/m)``, :data:`BODY_GYRATION_RANGE_M` (warn), never below a lead sphere's of
  the same mass (:func:`smallest_gyration_m`);
- a balance's mean reading against its stated accuracy: within the accuracy of zero is
  an empty pan (:func:`check_balance_reading`, refused);
- a pose's position, ``|x|, |y| <=`` :data:`POSE_MAX_M` (refused by row: a run in
  millimetres stays below it and is flagged by the estimators' residual check);
- a duty, 0..100 % (refused by row), and a duty range LOW..HIGH given reversed
  (:func:`check_duty_range`, refused saying so);
- a thrust calibration factor (efficiency, nozzle scale), :data:`FACTOR_RANGE` (warn); one
  near zero (:data:`DEAD_FACTOR`, or within 3 sigma of 0) names a dead or blocked thruster,
  a negative one a reversed or mis-wired thruster (:func:`thruster_factor_warnings`, warn);
- a time stamp: finite (:func:`check_finite_time`, refused);
- the modules of a structure: no two closer than :data:`MODULE_MIN_SPACING_M` (refused:
  they would overlap).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from common.constants import ARM_M
from common.errors import UserError

# ------------------------------------------------------------------ a body: mass and Izz

BODY_MASS_RANGE_KG = (0.05, 200.0)
"""A body on an air table, kg: a module is 0.7 kg; a structure of several a few kg."""
BODY_GYRATION_RANGE_M = (0.01, 2.0)
"""Radius of gyration ``sqrt(Izz/m)`` of such a body, m."""
DENSEST_KG_M3 = 11340.0
"""Lead: no body of a given mass is more compact than a lead sphere."""


def smallest_gyration_m(mass_kg: float) -> float:
    """Radius of gyration about a vertical axis of a lead sphere of ``mass_kg``: no body
    of that mass has a smaller one."""
    r = (3.0 * mass_kg / (4.0 * math.pi * DENSEST_KG_M3)) ** (1.0 / 3.0)
    return math.sqrt(0.4) * r


def mass_problem(mass_kg: float) -> str:
    """'' or ``"mass X kg is outside 0.05-200 kg"``."""
    lo, hi = BODY_MASS_RANGE_KG
    m = float(mass_kg)
    return "" if math.isfinite(m) and lo <= m <= hi else f"mass {m:.3g} kg is outside {lo:g}-{hi:g} kg"


def gyration_problem(mass_kg: float, izz_kgm2: float, *, whole_body: bool = True) -> str:
    """'' or what is wrong with ``izz_kgm2`` for ``mass_kg``: a radius of gyration outside
    :data:`BODY_GYRATION_RANGE_M` (``whole_body``; a part may be smaller) or below a lead
    sphere's; a non-positive Izz (``whole_body``)."""
    glo, ghi = BODY_GYRATION_RANGE_M
    m, izz = float(mass_kg), float(izz_kgm2)
    if math.isfinite(m) and m > 0 and math.isfinite(izz) and izz > 0:
        k = math.sqrt(izz / m)
        k_min = smallest_gyration_m(m)
        if whole_body and not glo <= k <= ghi:
            return (f"Izz {izz:.3g} kg m^2 for {m:.3g} kg is a radius of gyration of {k:.3g} m, "
                    f"outside {glo * 100:g} cm-{ghi:g} m")
        if k < k_min:
            return (f"Izz {izz:.3g} kg m^2 for {m:.3g} kg is a radius of gyration of "
                    f"{k * 100:.3g} cm, less than any body of {m:.3g} kg can have "
                    f"({k_min * 100:.3g} cm, a lead sphere)")
        return ""
    if whole_body and not (math.isfinite(izz) and izz > 0):
        return f"Izz {izz:.3g} kg m^2 is not positive"
    return ""


def body_problems(mass_kg: float, izz_kgm2: float | None = None) -> list[str]:
    """What is implausible about a whole body's mass (and Izz, when given)."""
    out = [mass_problem(mass_kg)]
    if izz_kgm2 is not None:
        out.append(gyration_problem(mass_kg, izz_kgm2))
    return [p for p in out if p]


# ------------------------------------------------------------------ a balance reading


def check_balance_reading(mean_kg: float, accuracy_kg: float, what: str = "the mean reading") -> None:
    """Refuse a mean reading within the balance's stated accuracy of zero: the pan is empty
    (or the balance was tared with the load on it); the relative uncertainty is 58 % or more."""
    if accuracy_kg > 0 and abs(mean_kg) <= accuracy_kg:
        raise UserError(f"{what} {mean_kg * 1e3:.4g} g is within the balance's accuracy "
                        f"+-{accuracy_kg * 1e3:g} g of zero: is the pan empty, or was the balance "
                        "tared with the module on it? Put the module on the zeroed balance")


def balance_mass_warnings(mass_kg: float, unit: str | None = None) -> list[str]:
    """A weighed body's mass outside :data:`BODY_MASS_RANGE_KG`, naming the reading unit."""
    p = mass_problem(mass_kg)
    if not p:
        return []
    said = f"{unit!r}" if unit else "the unit you meant"
    return [f"{p}: implausible for an air-table module or structure; are the readings in "
            f"{said} (--unit, or the unit written beside each reading)?"]


# ------------------------------------------------------------------ poses, duties, times

POSE_MAX_M = 1e5
"""No air table or motion-capture volume is 100 km across: a larger |x| or |y| is a damaged
row. Poses in millimetres (a 10 m volume: 1e4) stay below it; the estimators flag them by
their residuals."""


def check_pose_rows(pose: np.ndarray, line_no: Sequence[int] | np.ndarray, path: object) -> None:
    """Refuse the first pose row whose x or y is beyond :data:`POSE_MAX_M`, naming file and line."""
    xy = np.abs(np.asarray(pose, float)[:, :2])
    bad = np.nonzero((xy > POSE_MAX_M).any(axis=1))[0]
    if bad.size:
        i = int(bad[0])
        col = "x" if xy[i, 0] > POSE_MAX_M else "y"
        raise UserError(f"{path}: line {int(line_no[i])}: {col} = {pose[i, 0 if col == 'x' else 1]:g} m "
                        f"is not a position on an air table (|x|, |y| up to {POSE_MAX_M:g} m); "
                        "a damaged row?")


DUTY_RANGE_PCT = (0.0, 100.0)


def check_duty_rows(duty: np.ndarray, line_no: Sequence[int] | np.ndarray, path: object,
                    valid_pct: tuple[float, float] | None = None) -> None:
    """Refuse the first command row with a duty outside 0..100 % (and, with ``valid_pct``,
    an open duty outside a thrust table's valid range), naming file and line."""
    d = np.asarray(duty, float)
    lo, hi = DUTY_RANGE_PCT
    bad = (d < lo) | (d > hi)
    if bad.any():
        row = int(np.argwhere(bad)[0][0])
        raise UserError(f"{path}: line {int(line_no[row])}: duty outside 0..100 %")
    if valid_pct is not None:
        vlo, vhi = valid_pct
        bad = (d > 0) & ((d < vlo) | (d > vhi))
        if bad.any():
            row, col = (int(v) for v in np.argwhere(bad)[0])
            raise UserError(f"{path}: line {int(line_no[row])}: duty d{col + 1} = {d[row, col]:g} % "
                            f"is outside the thrust table's valid range {vlo:g}-{vhi:g} %")


def check_duty_range(lo: float, hi: float, what: str, fix: str | None = None) -> None:
    """Refuse a duty range LOW..HIGH given the other way round, saying so (``fix``: how to
    write it the right way round, default ``HIGH`` first)."""
    if lo > hi:
        raise UserError(f"{what}: the range {lo:g}..{hi:g} % is reversed (LOW above HIGH); "
                        f"{fix or f'give {hi:g} first'}")


def check_finite_time(t: float | None, what: str) -> None:
    """Refuse a time stamp that is NaN or infinite (None: not given, fine)."""
    if t is not None and not math.isfinite(float(t)):
        raise UserError(f"{what} must be a finite time in seconds, got {t!r}")


# ------------------------------------------------------------------ thrust calibration

MISFIT_CAUSES = (
    "likely causes: a valve dead time (the thrust starts and stops later than the command), "
    "a shared supply (thrust dropping with the number of valves open), damping (air-bearing "
    "drag, a tilted table), a dead or reversed thruster. Tell them apart: 'tpods estimate "
    "batch --delay-scan' (likelihood-ratio test of a dead time), '--model friction' or "
    "'--model auto' (damping, tilt), 'tpods calibrate thrust --per thruster' with the mass "
    "known (a dead, weak or reversed thruster) and '--per nozzles' (a shared-supply drop)")
"""What a model misfit (residuals, a factor far from 1) may mean, and the checks that tell
the causes apart."""

FACTOR_RANGE = (0.5, 1.5)
"""A thrust calibration factor (efficiency, nozzle scale): a thruster giving less than half
or more than 1.5x its table's thrust is broken, or the run is not of the stated body."""


def factor_warnings(names: Sequence[str], values: Sequence[float]) -> list[str]:
    """One line naming every calibration factor outside :data:`FACTOR_RANGE`."""
    lo, hi = FACTOR_RANGE
    bad = [f"{n} = {100 * v:.0f} %" for n, v in zip(names, values, strict=True)
           if not lo <= v <= hi]
    if not bad:
        return []
    return [f"{', '.join(bad)}: outside {100 * lo:.0f}-{100 * hi:.0f} % of the table's thrust; "
            "is the run of the body of --mass and --izz, and the table's unit right? "
            f"Do not use this table before checking. If they are: the model misses an "
            f"effect; {MISFIT_CAUSES}"]


DEAD_FACTOR = 0.3
"""A calibration factor below this (or within :data:`ZERO_SIGMAS` sigma of 0) is a thruster
that gives almost no thrust: dead or blocked."""
ZERO_SIGMAS = 3.0


def _factor_subject(name: str) -> str:
    kind, _, idx = name.partition(".")
    if kind == "efficiency":
        return f"thruster {idx} (column d{idx})"
    if kind == "nozzle_scale":
        return f"every thruster when {idx} are open"
    return "every thruster"


def thruster_factor_warnings(names: Sequence[str], values: Sequence[float],
                             sigma: Sequence[float]) -> list[str]:
    """One line per factor that names a dead or blocked thruster (near zero: below
    :data:`DEAD_FACTOR` or within :data:`ZERO_SIGMAS` sigma of 0) or a reversed or
    mis-wired one (negative beyond that), with the check that tells; then
    :func:`factor_warnings` on the others."""
    out, rest = [], []
    for n, v, s in zip(names, values, sigma, strict=True):
        v, s = float(v), float(s)
        said = f"{_factor_subject(n)}: {n} = {v:.3g} +- {s:.2g}"
        if v < 0 and abs(v) > ZERO_SIGMAS * s:
            out.append(f"{said} is negative: it pushes the wrong way. Reversed or mis-wired: its "
                       "valve is driven by another command column, or the nozzle points the "
                       "other way; check the valve wiring against the command column order "
                       "(open that valve alone and watch which way the body moves)")
        elif v < DEAD_FACTOR or abs(v) <= ZERO_SIGMAS * s:
            out.append(f"{said} is near zero: it gives almost no thrust. Dead or blocked: a valve "
                       "that does not open, a pinched or blocked tube, a broken wire, the "
                       "supply closed; check by opening that valve alone (listen for the jet, "
                       "watch the body move)")
        else:
            rest.append((n, v))
    return out + factor_warnings([n for n, _ in rest], [v for _, v in rest])


# ------------------------------------------------------------------ structures

MODULE_MIN_SPACING_M = 2 * ARM_M
"""Two module centres closer than twice the thruster arm: their valve blocks overlap."""


def check_module_spacing(names: Sequence[str], positions_m: Sequence[tuple[float, float]],
                         source: str, min_m: float = MODULE_MIN_SPACING_M) -> None:
    """Refuse two modules of a structure whose centres are closer than ``min_m``."""
    for i in range(len(positions_m)):
        for j in range(i):
            d = math.dist(positions_m[i], positions_m[j])
            if d < min_m:
                raise UserError(f"{source}: modules {names[j]!r} and {names[i]!r} are "
                                f"{d * 100:.3g} cm apart (position_m), less than a module's "
                                f"width {min_m * 100:g} cm: they would overlap; check position_m")
