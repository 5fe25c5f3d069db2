"""Structure runs that cannot determine their unknowns: refused, naming them.

A structure's fit estimates mass, Izz about the centre of mass and the centre of mass
``(cx, cy)`` in the tracked frame. Its yaw rate obeys ``rdot = (Mz - (cx Fy - cy Fx)) / Izz``
with ``Mz`` the thrusters' moment about the tracked origin. When no command produces a
moment about the origin (``Mz = 0`` in every row: e.g. symmetric modules only pushing the
structure along), the structure turns only by the moment of the thrust about its centre of
mass. With the centre of mass at (or very near) the origin it does not turn, and the run fixes
only ``cx/Izz`` and ``cy/Izz`` (both zero): Izz is undetermined, and with it cx and cy (any
centre of mass fits as well with a large enough Izz). Mass stays determined by the force.
(With the centre of mass well off the origin the same commands do turn the structure, and
everything is determined: such a run is not refused.)

:func:`refuse_undetermined` raises :class:`common.errors.UserError` (one line) for such
a fit, and for any fit whose estimated parameters have no information (infinite sigma).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from common.errors import UserError
from estimator.batch.least_squares import BatchResult, no_information
from estimator.plant.model import ARM_M, wrench

IZZ_REL_LIMIT = 0.5
"""Izz whose 1-sigma exceeds this fraction of its value counts as undetermined when the
commands give no moment about the tracked origin."""


def no_origin_moment(thrust_n: np.ndarray, arm_m: float = ARM_M) -> bool:
    """True when some row has a thrust and no row has a moment about the tracked origin
    (relative to the largest force times 1 m: virtual thrusts cancel to rounding)."""
    w = wrench(np.asarray(thrust_n, float), arm_m)
    force = float(np.max(np.hypot(w[:, 0], w[:, 1]))) if len(w) else 0.0
    return force > 0 and float(np.max(np.abs(w[:, 2]))) <= 1e-9 * force


def undetermined(res: BatchResult, thrust_n: np.ndarray, arm_m: float = ARM_M,
                 extent_m: float | None = None) -> tuple[tuple[str, ...], str]:
    """``(names, why)`` of the structure fit's parameters the run cannot determine; ``((),
    "")`` when it determines them all. ``extent_m``: the structure's size (its modules'
    farthest thruster from the tracked origin); a centre of mass whose sigma exceeds it is
    not located by the run."""
    names = tuple(res.names)
    if not np.any(np.asarray(thrust_n) != 0):
        return names, no_information(names, np.full(len(res.sigma), np.inf), thrust_n).split(
            " (infinite sigma): ", 1)[-1]
    if "izz" in names and no_origin_moment(thrust_n, arm_m):
        j = 6 + names.index("izz")
        izz, sig = float(res.z0[j]), float(res.sigma[j])
        if not (res.converged and math.isfinite(sig) and izz > 0 and sig <= IZZ_REL_LIMIT * izz):
            bad = tuple(n for n in ("izz", "cx", "cy") if n in names)
            how = (f"Izz {izz:.3g} +/- {sig:.3g} kg m^2" if math.isfinite(sig) and res.converged
                   else "the fit does not converge")
            why = ("no command produces a torque about the tracked origin, so the structure "
                   "turns only by the moment of the thrust about its centre of mass, "
                   "(cy Fx - cx Fy)/Izz, and this run does not separate Izz from cx, cy (a "
                   f"centre of mass at the origin: no turn at all; {how})")
            return bad, why
    bad = tuple(n for j, n in enumerate(names) if not math.isfinite(float(res.sigma[6 + j])))
    if bad:
        return bad, no_information(names, res.sigma, thrust_n).split(" (infinite sigma): ", 1)[-1]
    if extent_m is not None:
        wide = [(n, float(res.sigma[6 + names.index(n)])) for n in ("cx", "cy") if n in names]
        wide = [(n, s) for n, s in wide if s > extent_m]
        if wide:
            return (tuple(n for n, _ in wide),
                    "the centre of mass is not located within the structure's size "
                    f"({', '.join(f'{n} sigma {s:.3g} m' for n, s in wide)} > {extent_m:.3g} m): "
                    "the run turns the structure too little for the tracked frame's offset to "
                    "show (thrust in more directions, and torque, locate it)")
    return (), ""


def structure_extent_m(structure) -> float:
    """The farthest thruster of a :class:`common.structure.Structure` (a module's centre
    distance plus its thrusters' arm) or :class:`common.vehicle.Vehicle` from its tracked
    origin, m."""
    return structure.extent_m()


def refuse_undetermined(res: BatchResult, thrust_n: np.ndarray, where: str = "this run",
                        arm_m: float = ARM_M, fixed: Sequence[str] = (),
                        structure=None) -> None:
    """Raise a one-line UserError naming the parameters ``where`` cannot determine and why;
    return when it determines all of them. ``structure`` (optional) gives the size a
    centre of mass's sigma must stay within."""
    extent = structure_extent_m(structure) if structure is not None else None
    bad, why = undetermined(res, thrust_n, arm_m, extent)
    if not bad:
        return
    hint = ("; play commands that turn the structure (e.g. tpods sim --input phase-sine, "
            "or tpods design --structure) or fix Izz (--fixed izz=VALUE)"
            if "izz" in bad and "izz" not in fixed else "")
    raise UserError(f"{where}: {', '.join(bad)} cannot be estimated ({'it is' if len(bad) == 1 else 'they are'} "
                    f"undetermined): {why}{hint}")


def refuse_undetermined_run(run, table, *, names: Sequence[str], fixed, clamp: bool = False,
                            sigma_pos_m: float = 0.01, sigma_yaw_rad: float = math.radians(1.0)
                            ) -> None:
    """The check of :func:`refuse_undetermined` for a filter on a structure run
    (:class:`common.runfolder.Run` with its structure): a filter cannot tell an undetermined
    parameter (it reports its prior shrunk by a wrong linearisation), so when the commands
    give no moment about the tracked origin the batch fit of the same run decides. Other
    runs return at once (no fit)."""
    from estimator.batch.least_squares import estimate_run as least_squares_run

    cmd_t, thrust = run.thrust_profile(table, clamp=clamp)
    if np.any(thrust != 0) and not no_origin_moment(thrust):
        return
    start = {k: v for k, v in run.structure.initial_guess().items() if k in names}
    res = least_squares_run(run, table, (None, None), clamp=clamp, names=tuple(names),
                            fixed=dict(fixed), initial=start, sigma_pos_m=sigma_pos_m,
                            sigma_yaw_rad=sigma_yaw_rad, thrust_uncertainty=False)
    refuse_undetermined(res, thrust, str(run.path), fixed=tuple(fixed), structure=run.structure)
