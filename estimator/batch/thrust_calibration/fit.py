"""The thrust calibration problem and its solver (:mod:`estimator.batch.thrust_calibration.calibrate`):
residuals and Jacobian on the poses up to a horizon (:class:`CalibrationFit`), damped
Gauss-Newton on one horizon (:func:`gauss_newton`), and whether a run separates the
factors at all (:func:`confounded`, :func:`worst_combination`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from common.errors import UserError
from estimator.batch.consider import output_sensitivity, segment_jacobian
from estimator.batch.crlb import make_grid, reference_states, safe_inverse, trajectory_stm
from estimator.batch.thrust_factors import factor_thrust
from estimator.plant.model import wrap_angle
from estimator.plant.output import output_jacobian, tracked_pose

MODEL_EXTRAS = {"ideal": (), "friction": ("ct", "cr", "kb"),
                "friction+tilt": ("ct", "cr", "kb", "ax", "ay")}
"""Nuisance parameters estimated beside the factors, per ``--model``."""

MIN_EIGENVALUE = 1e-10
"""Smallest eigenvalue of the unit-diagonal factor information below which the factors are
confounded (numerically singular). A well-posed run can come close to 1e-5: the
efficiencies' differences are then far better determined than their common level."""

MAX_COMBINATION_SIGMA = 0.1
"""Largest standard deviation (noise part) of any combination of the factors (unit
vector) a run may leave: beyond it the run hardly separates them (near-confounding)."""

START_PRIOR = 0.05**-2
"""Information (per unit factor squared) of the pseudo-prior that holds the factors near
their start on the start-up stages of the growing horizon (a 5 % sigma); the final stage
has none."""


def confounded(info: np.ndarray, names: Sequence[str]) -> tuple[float, tuple[str, ...]]:
    """Smallest eigenvalue of the unit-diagonal information on the factors and the factors
    that dominate its eigenvector, read in factor units (components of at least a quarter
    of the largest)."""
    d = np.sqrt(np.abs(np.diag(info)))
    if np.any(d == 0):
        zero = tuple(n for n, x in zip(names, d, strict=True) if x == 0)
        return 0.0, zero
    A = info / np.outer(d, d)
    w, V = np.linalg.eigh(0.5 * (A + A.T))
    v = np.abs(V[:, 0] / d)  # back in factor units (every factor is a relative scale)
    return float(w[0]), tuple(n for n, x in zip(names, v, strict=True) if x >= 0.25 * v.max())


def worst_combination(info: np.ndarray, names: Sequence[str]) -> tuple[float, tuple[str, ...]]:
    """Standard deviation of the least determined unit combination of the factors (from the
    marginal information ``info``) and the factors that dominate it."""
    w, V = np.linalg.eigh(0.5 * (info + info.T))
    if w[0] <= 0:
        return math.inf, tuple(names)
    v = np.abs(V[:, 0])
    return float(w[0] ** -0.5), tuple(n for n, x in zip(names, v, strict=True) if x >= 0.25 * v.max())


def describe_confounding(names: Sequence[str], lam: float, sigma: float | None = None) -> str:
    effs = [n for n in names if n.startswith("efficiency.")]
    scales = [n for n in names if n.startswith("nozzle_scale.")]
    if len(effs) >= 3 and scales:
        what = (f"{', '.join(scales)} with the common level of the efficiencies "
                f"({', '.join(effs)}): thrust only sees their product")
    else:
        what = ", ".join(names)
    why = (f"smallest eigenvalue of the equilibrated information {lam:.2g} < {MIN_EIGENVALUE:g}"
           if sigma is None else
           f"their least determined combination has sigma {sigma:.2g} > {MAX_COMBINATION_SIGMA:g}")
    return (f"the run cannot separate the factors: {what} ({why}); use a run that opens "
            "the thrusters in different combinations and numbers (e.g. 'tpods design --for "
            "thrust-calibration'), or estimate fewer factors (--per)")


class CalibrationFit:
    """Residuals and Jacobian of the calibration problem on the poses up to a horizon."""

    def __init__(self, pose_t, pose, cmd_t, duty, table, names, extras, fixed, w, clamp, max_step):
        self.pose_t, self.pose, self.cmd_t, self.duty = pose_t, pose, cmd_t, duty
        self.table, self.names, self.extras, self.fixed = table, names, extras, fixed
        self.w, self.clamp, self.max_step = w, clamp, max_step
        self.ne = 6 + len(extras)
        # the known values carried as consider parameters (Izz too unless it is estimated)
        self.consider = tuple(c for c in ("mass", "izz") if c not in extras)

    def split(self, z):
        return z[:6], z[6:self.ne], z[self.ne:]

    def setup(self, z):
        s0, ex, f = self.split(z)
        if hasattr(self.table, "factor_thrust"):  # a vehicle's (thrust_calibration_vehicle)
            thrust, fjac = self.table.factor_thrust(self.names, f)
        else:
            thrust, fjac = factor_thrust(self.table, self.duty, self.names, f, self.clamp)
        params = dict(self.fixed)
        params.update({n: float(v) for n, v in zip(self.extras, ex, strict=True)})
        grid = make_grid(self.cmd_t, thrust, self.pose_t, self.max_step)
        return params, grid, fjac

    def evaluate(self, z):
        """``(cost, residuals (N, 3), cache)``; cost inf for a non-finite trajectory or a
        non-positive estimated Izz (a factor may be 0 or negative: a dead or reversed
        thruster)."""
        if not np.all(np.isfinite(z)):
            return math.inf, None, None
        if "izz" in self.extras and z[6 + self.extras.index("izz")] <= 0:
            return math.inf, None, None
        params, grid, fjac = self.setup(z)
        with np.errstate(all="ignore"):
            try:
                states = reference_states(z[:6], grid, params)
            except (OverflowError, ValueError):  # the scalar RK4 loop's math errors
                return math.inf, None, None
        if not np.all(np.isfinite(states)):
            return math.inf, None, None
        res = self.pose - tracked_pose(states[grid.node_pos], params.get("cx", 0.0),
                                       params.get("cy", 0.0))
        res[:, 2] = wrap_angle(res[:, 2])
        return float(np.sum(res**2 * self.w)), res, (params, grid, fjac, states)

    def jacobian(self, z, cache):
        """``(H (N, 3, 6+e+P), Jmi (N, 3, c))``: d pose / d z and d pose / d (the consider
        parameters :attr:`consider`: mass, and izz when it is known)."""
        params, grid, fjac, states = cache
        with np.errstate(all="ignore"):
            _, phi = trajectory_stm(z[:6], None, None, self.pose_t, params,
                                    self.extras + self.consider, grid=grid, states=states)
            Jf = output_sensitivity(states, grid, params, segment_jacobian(grid, fjac))
        # the tracked pose's (the centre of mass offset cx, cy; phi[:, :3] exactly without)
        Hs = output_jacobian(states[grid.node_pos], phi, self.extras + self.consider,
                             *self.offset(params))
        Jf = output_jacobian(states[grid.node_pos], Jf, (), *self.offset(params))
        H = np.concatenate([Hs[:, :, :self.ne], Jf], axis=-1)
        return H, Hs[:, :, self.ne:]

    @staticmethod
    def offset(params) -> tuple[float, float]:
        """The centre of mass's offset ``(cx, cy)`` from the tracked origin, m."""
        return float(params.get("cx", 0.0)), float(params.get("cy", 0.0))


def normal_equations(H, w, res):
    """``(Lambda, lambda)``: ``sum H^T W H`` and ``sum H^T W r`` for H (N, 3, n), w (3,),
    r (N, 3)."""
    Lam = np.einsum("kin,i,kim->nm", H, w, H, optimize=True)
    lam = np.einsum("kin,i,ki->n", H, w, res, optimize=True)
    return Lam, lam


def solve_damped(Lam, lam, scale, mu):
    A = Lam * np.outer(scale, scale)
    d = np.sqrt(np.maximum(np.diag(A), 1e-300))
    An = A / np.outer(d, d) + mu * np.eye(len(d))
    y = np.linalg.lstsq(An, lam * scale / d, rcond=1e-14)[0]
    return y / d * scale


def gauss_newton(fit: CalibrationFit, z, scale, *, reg: float, tol: float, tol_sigma: float | None,
                  max_iter: int, stats: dict):
    """LM iterations on one horizon; a weak pseudo-prior ``reg`` (information per unit
    factor^2) ties the factors to their start on the start-up stages."""
    anchor = z.copy()
    wreg = np.zeros(len(z))
    wreg[fit.ne:] = reg
    cost, res, cache = fit.evaluate(z)
    if not math.isfinite(cost):
        raise UserError("the start gives a non-finite trajectory (check --mass and --izz)")
    mu = 0.0
    H, _ = fit.jacobian(z, cache)
    Lam, lam = normal_equations(H, fit.w, res)
    converged = False
    for _ in range(max_iter):
        L = Lam + np.diag(wreg)
        step = solve_damped(L, lam - wreg * (z - anchor), scale, mu)
        fstep = np.max(np.abs(step[fit.ne:]), initial=0.0)
        if fstep > 0.2:  # no factor moves by more than 0.2 per step
            step *= 0.2 / fstep
        if "izz" in fit.extras:  # nor an estimated Izz by more than half its value
            i = 6 + fit.extras.index("izz")
            if abs(step[i]) > 0.5 * z[i]:
                step *= 0.5 * z[i] / abs(step[i])
        small = bool(np.max(np.abs(step / scale)) < tol)
        if tol_sigma is not None and mu == 0.0:
            sig = np.sqrt(np.maximum(np.diag(safe_inverse(L)), 1e-300))
            small = small or bool(np.max(np.abs(step) / sig) < tol_sigma)
        z_new = z + step
        c_new, r_new, cache_new = fit.evaluate(z_new)
        c_tot = cost + float(np.sum(wreg * (z - anchor) ** 2))
        c_new_tot = c_new + float(np.sum(wreg * (z_new - anchor) ** 2))
        if c_new_tot <= c_tot * (1 + 1e-12) + 1e-12:
            z, cost, res, cache = z_new, c_new, r_new, cache_new
            stats["iterations"] += 1
            mu = 0.0 if mu < 1e-6 else mu / 10
            if small:
                converged = True
                break
            H, _ = fit.jacobian(z, cache)
            Lam, lam = normal_equations(H, fit.w, res)
        else:
            if small:
                converged = True
                break
            mu = 1e-4 if mu == 0.0 else mu * 10
            if mu > 1e10:
                break
    return z, converged, cost, res, cache
