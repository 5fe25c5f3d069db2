"""In-situ calibration of a vehicle or structure: the thrust factors of a
body described by thrusters rather than by one module's table.

Works on the interface :class:`common.structure.Structure` has and a vehicle
(``common/vehicle.py``) will have: ``n_channels``, ``thrust_n(duty)`` (per physical
thruster, N), ``module_wrench_matrix()`` (3, C: body Fx, Fy, Mz about the tracked origin per
newton of each thruster) and ``virtual_sensitivity(duty)`` (its stated thrust uncertainty,
mapped to the plant's virtual thrusts). The plant takes the four *virtual* thrusts of one
module at the tracked origin (``V = pinv(W1) W``, W1 the module's wrench matrix at the
plant's arm), so the factors act on the physical thrusts and reach the plant through V:

- ``efficiency.J`` (``--per thruster``): thruster J's thrust times its factor, J = 1..C in
  the vehicle's thruster (command column) order;
- ``scale`` (``--per common``): every thrust times one factor.

The thrusts reach the plant through the vehicle's known valve timing (vehicle.toml
``[valves]`` dead time and rise, :meth:`common.vehicle.Vehicle.through_valves`: linear in
the thrusts, so the factors' derivatives take the same path); :attr:`VehicleThrust.hold_t`
are the held rows' times (the commands' own without timing).

Nozzle-count factors (``--per nozzles|both``) belong to a thrust table and are refused here.
Like the table path the factors are applied outside the thrust model, so a dead (0) or
reversed (negative) thruster can be estimated. The stated uncertainty's terms that the
factors absorb exactly on this run's command rows (their virtual-thrust derivative a fixed
combination of the factors') are dropped from the consider covariance
(:func:`absorbed_on_rows`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from common.errors import UserError
from common.structure import module_wrench_1
from common.thrust_uncertainty import ThrustSensitivity

VEHICLE_PER = ("thruster", "common")
ABSORB_TOL = 1e-9


def is_vehicle(thrust_model) -> bool:
    """True for a structure or vehicle (thrusters as data), False for a thrust table."""
    return hasattr(thrust_model, "module_wrench_matrix") and hasattr(thrust_model, "n_channels")


class VehicleThrust:
    """The thrusts of a vehicle's commands with the in-situ factors applied, as the plant
    takes them (virtual), and their derivatives."""

    def __init__(self, vehicle, duty_pct: np.ndarray, arm_m: float, clamp: bool = False,
                 cmd_t: np.ndarray | None = None):
        d = np.asarray(duty_pct, float)
        if d.shape[-1] != vehicle.n_channels:
            raise UserError(f"the vehicle has {vehicle.n_channels} thrusters, the commands "
                            f"{d.shape[-1]} columns")
        self.vehicle = vehicle
        self.phys = np.asarray(vehicle.thrust_n(d, clamp=clamp), float)  # (Nc, C)
        W = np.asarray(vehicle.module_wrench_matrix(), float)  # (3, C)
        self.V = np.linalg.pinv(module_wrench_1(arm_m)) @ W  # (4, C)
        self.cmd_t = None if cmd_t is None else np.asarray(cmd_t, float)
        self.timed = self.cmd_t is not None and hasattr(vehicle, "through_valves")
        self.base = self.phys @ self.V.T  # (Nc, 4) virtual thrusts without factors
        # the rise cuts a hold where its values change: the rows of the factor-free thrusts,
        # which every factored thrust and derivative shares (each carries them along)
        self.hold_t = (self.cmd_t if not self.timed else
                       vehicle.through_valves(self.cmd_t, self.base)[0])

    def factor_thrust(self, names: Sequence[str], values: Sequence[float]
                      ) -> tuple[np.ndarray, np.ndarray]:
        """Virtual thrusts (Nc, 4) N with the factors and their derivatives (Nc, 4, P), on
        the rows of :attr:`hold_t` (the valves' timing applied when ``cmd_t`` was given)."""
        col = np.ones(self.phys.shape[-1])
        scale = 1.0
        for n, v in zip(names, values, strict=True):
            if n == "scale":
                scale = float(v)
            else:
                col[int(n.split(".")[1]) - 1] = float(v)
        thrust = (self.phys * col * scale) @ self.V.T
        jac = np.zeros(thrust.shape + (len(names),))
        for i, n in enumerate(names):
            if n == "scale":
                jac[..., i] = (self.phys * col) @ self.V.T
            else:
                j = int(n.split(".")[1]) - 1
                jac[..., i] = np.outer(self.phys[:, j] * scale, self.V[:, j])
        if self.timed:  # on the rows of hold_t: through the valves' dead time and rise
            n = len(self.cmd_t)
            rows = np.concatenate([self.base, thrust, jac.reshape(n, -1)], axis=1)
            rows = self.vehicle.through_valves(self.cmd_t, rows)[1]
            thrust = rows[:, 4:8]
            jac = rows[:, 8:].reshape((len(rows),) + jac.shape[1:])
        return thrust, jac


def check_per(per: str) -> None:
    if per not in VEHICLE_PER:
        raise UserError(f"--per {per}: nozzle-count factors belong to a thrust table; a vehicle "
                        f"or structure is calibrated --per {' or --per '.join(VEHICLE_PER)}")


def absorbed_on_rows(sens: ThrustSensitivity, factor_jac: np.ndarray) -> tuple[str, ...]:
    """The terms of ``sens`` whose virtual-thrust derivative on these rows is exactly a
    combination of the factors' (``factor_jac`` (Nc, 4, P)): a calibration absorbs them."""
    A = np.asarray(factor_jac, float).reshape(-1, factor_jac.shape[-1])
    out = []
    for i, n in enumerate(sens.names):
        b = np.asarray(sens.jacobian[..., i], float).reshape(-1)
        nb = np.linalg.norm(b)
        if nb == 0 or A.shape[1] == 0:
            continue
        x = np.linalg.lstsq(A, b, rcond=None)[0]
        if np.linalg.norm(A @ x - b) <= ABSORB_TOL * nb:
            out.append(n)
    return tuple(out)


def calibrated_vehicle(vehicle, names: Sequence[str], values: Sequence[float],
                       cov: np.ndarray, source: str):
    """A copy of ``vehicle`` (a :class:`common.vehicle.Vehicle` of on/off valves) with the
    in-flight factors in its valves' ``force_n`` and their sigma in ``force_sigma_n``
    (the factor's sigma times the stated force: the new value carries the calibration's
    whole uncertainty, noise, known body and the stated forces'; correlations between
    the factors are left out). UserError for a thruster with a thrust table (a table's
    factors go into the table: ``tpods calibrate thrust --thrust-table``)."""
    from dataclasses import replace

    sig = np.sqrt(np.clip(np.diag(np.asarray(cov, float)), 0.0, None))
    factor = {}
    for n, v, s in zip(names, values, sig, strict=True):
        if n == "scale":
            factor.update({j: (float(v), float(s)) for j in range(vehicle.n_channels)})
        else:
            factor[int(n.split(".")[1]) - 1] = (float(v), float(s))
    thrusters = []
    for j, t in enumerate(vehicle.thrusters):
        if j not in factor:
            thrusters.append(t)
            continue
        if t.table is not None:
            raise UserError(f"{vehicle.source}: thruster {t.name} has a thrust table: its factor "
                            "cannot be written into vehicle.toml (calibrate the table with "
                            "--thrust-table)")
        v, s = factor[j]
        thrusters.append(replace(t, force_n=t.force_n * v, force_sigma_n=abs(t.force_n) * s))
    return replace(vehicle, thrusters=tuple(thrusters), source=source)
