"""In-situ thrust calibration: thruster efficiencies and nozzle-count scales from a run of a
body whose mass and Izz are known (issue 17, item 4).

The bench characterises one nozzle at a time; on the assembled module a pinched tube, a
worn seat or another PWM frequency changes one thruster's thrust. With m and Izz known
(balance, bifilar pendulum) the poses of a run determine the thrusts, so the table's
in-situ factors (:class:`common.thrust_uncertainty.ThrustCalibration`)

    T_ij = eff_j * nozzle_scale_k * poly_k(D_ij)      (channel j, row i, k nozzles open)

can be estimated. Unknowns: the initial state ``s0`` (6), the model's extra parameters
(``friction``: ct, cr, kb; ``friction+tilt``: also ax, ay) and the factors ``f`` (P,
dimensionless):

- ``per="thruster"``: ``efficiency.1..4`` (their common level included);
- ``per="nozzles"``: ``nozzle_scale.k`` for every count k the run uses;
- ``per="both"``: both. Thrust only sees the products ``eff_j * nozzle_scale_k``, so
  raising every efficiency by a factor and lowering every nozzle scale by it changes
  nothing: the nozzle scale of the *reference count* (the count the run holds longest) is
  kept at its value (1), the efficiencies carry the level and the other counts' scales
  are relative to it. A run with a single count has nothing to add to ``thruster``: it
  is refused (its nozzle scale is confounded with the efficiencies' common level).

Fit: Gauss-Newton / Levenberg-Marquardt on ``sum_k r_k^T W r_k`` with ``r_k`` pose minus
prediction (yaw wrapped), over a growing horizon (5 s or 1 rad of yaw, then doubling)
as in :mod:`estimator.batch.least_squares`. Jacobian columns: initial state and extras
from :func:`estimator.batch.crlb.trajectory_stm`; factors from
:func:`estimator.batch.consider.output_sensitivity` with ``dT_ij/d eff_j = T_ij/eff_j`` and
``dT_ij/d nozzle_scale_k = T_ij/nozzle_scale_k`` on rows with k open (exact, no finite
differences). Each iteration re-evaluates the thrusts with the current factors.

Covariance of the factors (total = sum of the parts, each reported):

- ``noise``: the factor block of ``Lambda^-1`` (measurement noise, nuisance marginalised);
- ``mass``, ``izz``: the known values' standard uncertainties carried as consider
  parameters (``S P_c S^T``, their output sensitivities are the mass/Izz columns of the
  transition matrix);
- ``table``: the table's own stated uncertainty (:func:`common.thrust_uncertainty.thrust_sensitivity`
  of a table holding only the factors *not* estimated). A term the estimated factors
  absorb exactly (``[uncertainty] scale_rel`` when the efficiencies are estimated,
  ``[uncertainty.nozzles.k]`` when ``nozzle_scale.k`` is) is calibrated away: it drops
  from the factors' covariance and from the new table (the calibrated thrust no longer
  depends on it). Terms not absorbed (fit coefficients) stay in the new table *and*
  enter the factors' covariance (conservative: their negative cross-covariance with the
  factors cannot be written in the table format).

Refusals (:class:`common.errors.UserError` naming the reason): a thruster never opened
(for efficiencies), a run without thrust, ``both`` on a single nozzle count, and any run
whose information on the factors is singular or nearly so: the smallest eigenvalue of
the equilibrated (unit-diagonal) factor information below :data:`MIN_EIGENVALUE`; the
factors named are those with a large share of its eigenvector.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from common.errors import UserError
from common.plausible import factor_warnings
from common.thrust_table import ThrustTable
from common.thrust_uncertainty import ThrustCalibration, ThrustUncertainty, thrust_sensitivity
from estimator.batch.consider import output_sensitivity, segment_jacobian
from estimator.batch.crlb import (
    DEFAULT_MAX_STEP_S,
    PARAM_SCALE,
    make_grid,
    marginal_information,
    reference_states,
    safe_inverse,
    trajectory_stm,
)
from estimator.batch.least_squares import residual_warnings
from estimator.plant.model import ARM_M, wrap_angle

PER_CHOICES = ("thruster", "nozzles", "both")
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

ABSORB_TOL = 1e-9
"""Relative residual below which a table term is exactly a combination of the factors."""

N_CHANNELS = 4

START_PRIOR = 0.05**-2
"""Information (per unit factor squared) of the pseudo-prior that holds the factors near
their start on the start-up stages of the growing horizon (a 5 % sigma); the final stage
has none."""


# ----------------------------------------------------------------------------- tables


def channel_name(j: int) -> str:
    """``efficiency.J`` of 0-based channel ``j``."""
    return f"efficiency.{j + 1}"


def with_factors(table: ThrustTable, names: Sequence[str], values: Sequence[float], *,
                 parameters: Sequence[str] = (), covariance: np.ndarray | None = None,
                 info: Mapping[str, Any] | None = None) -> ThrustTable:
    """``table`` with the factors ``names`` set to ``values`` (other factors as the table
    has them) and a calibration covariance over ``parameters`` (default: none)."""
    cal = table.calibration
    eff = list(table.channel_factors(N_CHANNELS))
    ns = dict(cal.nozzle_scale) if cal is not None else {}
    for n, v in zip(names, values, strict=True):
        kind, idx = n.split(".")
        if kind == "efficiency":
            eff[int(idx) - 1] = float(v)
        else:
            ns[int(idx)] = float(v)
    cov = np.zeros((0, 0)) if covariance is None else np.asarray(covariance, float)
    new = ThrustCalibration(tuple(float(e) for e in eff), ns, tuple(parameters), cov,
                            dict(info) if info is not None else {})
    return replace(table, calibration=new)


def factor_jacobian(table: ThrustTable, duty_pct: np.ndarray, names: Sequence[str],
                    clamp: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Thrusts ``(..., 4)`` N and their derivatives ``(..., 4, P)`` with respect to the
    factors ``names`` (N per unit factor): ``T_j/eff_j`` in channel j, ``T/nozzle_scale_k``
    on rows with k open."""
    thrust = table.thrust_n(duty_pct, clamp=clamp)
    k = (np.asarray(duty_pct) > 0).sum(axis=-1)
    eff = table.channel_factors(thrust.shape[-1])
    cols = []
    for n in names:
        kind, idx = n.split(".")
        if kind == "efficiency":
            j = int(idx) - 1
            col = np.zeros_like(thrust)
            col[..., j] = thrust[..., j] / eff[j]
        else:
            kk = int(idx)
            col = np.where((k == kk)[..., None], thrust / table.nozzle_factor(kk), 0.0)
        cols.append(col)
    jac = np.stack(cols, axis=-1) if cols else np.zeros(thrust.shape + (0,))
    return thrust, jac


def probe_rows(table: ThrustTable) -> np.ndarray:
    """(R, 4) duty rows covering every nozzle count of the table, every channel subset and
    duties across its valid range (for checks that must hold on any future run)."""
    lo, hi = table.duty_range
    levels = np.linspace(lo, hi, 4)
    rows = []
    for k in sorted(table.coefficients):
        if not 1 <= k <= N_CHANNELS:
            continue
        for sub in itertools.combinations(range(N_CHANNELS), k):
            for i, d in enumerate(levels):
                r = np.zeros(N_CHANNELS)
                r[list(sub)] = d
                rows.append(r)
                r2 = np.zeros(N_CHANNELS)
                r2[list(sub)] = levels[(i + np.arange(k)) % len(levels)]
                rows.append(r2)
    return np.array(rows)


def absorbed_terms(table: ThrustTable, names: Sequence[str]) -> tuple[str, ...]:
    """Table uncertainty terms (``scale``, ``scale.k``) that the factors ``names`` absorb
    exactly: on every duty row the table can be asked for, the term's thrust derivative
    is a fixed combination of the factors' derivatives, so a calibration shifts the
    factors by exactly the term's error and the calibrated thrust does not depend on it."""
    rows = probe_rows(table)
    base = with_factors(table, (), ())  # the factor values, no calibration covariance
    sens = thrust_sensitivity(base, rows)
    _, F = factor_jacobian(base, rows, names)
    A = F.reshape(-1, F.shape[-1])
    out = []
    for i, n in enumerate(sens.names):
        if not (n == "scale" or n.startswith("scale.")):
            continue
        b = sens.jacobian[..., i].reshape(-1)
        if A.shape[1] == 0:
            continue
        x = np.linalg.lstsq(A, b, rcond=None)[0]
        if np.linalg.norm(A @ x - b) <= ABSORB_TOL * max(np.linalg.norm(b), 1e-300):
            out.append(n)
    return tuple(out)


def remaining_uncertainty(unc: ThrustUncertainty | None, absorbed: Sequence[str]
                          ) -> ThrustUncertainty | None:
    """``unc`` without the absorbed terms (None when nothing is left and nothing was said)."""
    if unc is None:
        return None
    scale = 0.0 if "scale" in absorbed else unc.scale_rel
    per = {k: v for k, v in unc.nozzle_scale_rel.items() if f"scale.{k}" not in absorbed}
    sources = {k: v for k, v in unc.sources.items()
               if not (k == "scale_rel" and "scale" in absorbed)
               and not (k.startswith("nozzles.") and f"scale.{k.split('.')[1]}" in absorbed)}
    notes = unc.notes
    if absorbed:
        gone = ", ".join("scale_rel" if a == "scale" else f"nozzles.{a.split('.')[1]} scale_rel"
                         for a in absorbed)
        extra = f"calibrated away in situ (absorbed by [calibration]): {gone}"
        notes = f"{notes}; {extra}" if notes else extra
    return ThrustUncertainty(scale, per, sources, notes)


# ------------------------------------------------------------------------ the factors


def counts_used(duty_pct: np.ndarray, cmd_t: np.ndarray, t_end: float) -> dict[int, float]:
    """``{k: seconds held}`` for every nozzle count k > 0 the commands hold before ``t_end``."""
    d = np.asarray(duty_pct)
    t = np.asarray(cmd_t, float)
    ends = np.append(t[1:], max(t_end, t[-1]))
    dur = np.clip(np.minimum(ends, t_end) - t, 0.0, None)
    k = (d > 0).sum(axis=-1)
    out: dict[int, float] = {}
    for kk in np.unique(k):
        if kk > 0:
            out[int(kk)] = float(dur[k == kk].sum())
    return {kk: v for kk, v in out.items() if v > 0}


def factor_names(per: str, duty_pct: np.ndarray, cmd_t: np.ndarray, t_end: float
                 ) -> tuple[tuple[str, ...], int | None]:
    """The factors ``per`` asks for on this run and the reference count (``both``), or a
    UserError for a run that cannot give them (no thrust; a thruster never opened)."""
    if per not in PER_CHOICES:
        raise UserError(f"--per must be one of {', '.join(PER_CHOICES)}, got {per!r}")
    used = counts_used(duty_pct, cmd_t, t_end)
    if not used:
        raise UserError("the run never opens a thruster: no thrust, nothing to calibrate")
    d = np.asarray(duty_pct)
    t = np.asarray(cmd_t, float)
    live = t < t_end
    names: list[str] = []
    if per in ("thruster", "both"):
        never = [j + 1 for j in range(N_CHANNELS) if not np.any(d[live, j] > 0)]
        if never:
            which = ", ".join(str(j) for j in never)
            raise UserError(
                f"thruster{'s' if len(never) > 1 else ''} {which} {'is' if len(never) == 1 else 'are'} "
                f"never opened in this run: {'its efficiency' if len(never) == 1 else 'their efficiencies'} "
                "cannot be estimated (record a run that opens every thruster, e.g. "
                "translate-rotate or 'tpods design --for thrust-calibration', or use --per nozzles)")
        names += [channel_name(j) for j in range(N_CHANNELS)]
    ref = None
    if per in ("nozzles", "both"):
        ks = sorted(used)
        if per == "both" and len(ks) > 1:
            ref = max(ks, key=lambda kk: used[kk])
            ks = [kk for kk in ks if kk != ref]
        names += [f"nozzle_scale.{kk}" for kk in ks]
    return tuple(names), ref


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


def _describe_confounding(names: Sequence[str], lam: float, sigma: float | None = None) -> str:
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


# --------------------------------------------------------------------------- the fit


@dataclass
class ThrustCalibrationResult:
    """In-situ factors of a thrust table (dimensionless) with their uncertainty budget.

    Attributes:
        names: (P,) estimated factors (``efficiency.J``, ``nozzle_scale.K``).
        values: (P,) their estimates.
        cov: (P, P) total covariance = cov_noise + cov_mass + cov_izz + cov_table.
        cov_noise, cov_mass, cov_izz, cov_table: (P, P) the parts (measurement noise; the
            known mass's and Izz's uncertainty; the table's own stated uncertainty).
        table_terms: names of the table parameters carried in ``cov_table``.
        absorbed: table uncertainty terms the factors calibrate away (``scale``, ``scale.k``).
        reference_count: ``both``: the nozzle count whose scale stays fixed (else None).
        state0: (6,) initial state x, y (m), psi (rad), u, v (m/s), r (rad/s) at ``t0``.
        extras: estimated model parameters (ct, cr, kb, ax, ay; SI) with ``extras_sigma``.
        residuals: (N, 3) pose minus prediction (m, m, rad).
        min_eigenvalue: of the unit-diagonal factor information (1 = uncorrelated factors).
        correlation: (P, P) of the total covariance.
    """

    names: tuple[str, ...]
    values: np.ndarray
    cov: np.ndarray
    cov_noise: np.ndarray
    cov_mass: np.ndarray
    cov_izz: np.ndarray
    cov_table: np.ndarray
    table_terms: tuple[str, ...]
    absorbed: tuple[str, ...]
    reference_count: int | None
    per: str
    model: str
    state0: np.ndarray
    extras: dict[str, float]
    extras_sigma: dict[str, float]
    t0: float
    t: np.ndarray
    residuals: np.ndarray
    iterations: int
    converged: bool
    stages: list[float]
    min_eigenvalue: float
    known: dict[str, float]
    kept_cross: np.ndarray | None = None
    kept_names: tuple[str, ...] = ()
    warnings: list[str] = field(default_factory=list)

    @property
    def sigma(self) -> np.ndarray:
        return np.sqrt(np.maximum(np.diag(self.cov), 0.0))

    @property
    def correlation(self) -> np.ndarray:
        s = np.where(self.sigma > 0, self.sigma, 1.0)
        return self.cov / np.outer(s, s)

    def budget(self) -> dict[str, dict[str, float]]:
        """``{factor: {"noise", "mass", "izz", "table", "total"}}`` 1-sigma parts; their
        root-sum-square is the total."""
        out = {}
        for i, n in enumerate(self.names):
            parts = {k: float(math.sqrt(max(c[i, i], 0.0))) for k, c in
                     (("noise", self.cov_noise), ("mass", self.cov_mass), ("izz", self.cov_izz),
                      ("table", self.cov_table))}
            parts["total"] = float(self.sigma[i])
            out[n] = parts
        return out

    def limited_by(self) -> dict[str, str]:
        """The largest part of each factor's variance, in words."""
        words = {"noise": "measurement noise", "mass": "known mass uncertainty",
                 "izz": "known Izz uncertainty", "table": "thrust table uncertainty"}
        return {n: words[max(("noise", "mass", "izz", "table"), key=lambda k: b[k])]
                for n, b in self.budget().items()}

    def rms_residuals(self) -> np.ndarray:
        return np.sqrt(np.mean(self.residuals**2, axis=0))

    def new_table(self, table: ThrustTable, *, source: str = "tpods calibrate thrust",
                  run: str = "") -> ThrustTable:
        """``table`` with the factors and their covariance in ``[calibration]`` (original
        coefficients kept; absorbed ``[uncertainty]`` terms removed)."""
        names = list(self.names) + list(self.kept_names)
        P, K = len(self.names), len(self.kept_names)
        cov = np.zeros((P + K, P + K))
        cov[:P, :P] = self.cov
        if K:
            kept_cov = _kept_covariance(table, self.kept_names)
            cov[P:, P:] = kept_cov
            cov[:P, P:] = self.kept_cross
            cov[P:, :P] = self.kept_cross.T
        cov = 0.5 * (cov + cov.T)
        notes = []
        if self.reference_count is not None:
            notes.append(f"nozzle_scale.{self.reference_count} held fixed (reference count): "
                         "the efficiencies carry the common level, the other counts' scales "
                         "are relative to it")
        if self.absorbed:
            notes.append("calibrated away: " + ", ".join(self.absorbed))
        info = {"source": source, **({"run": run} if run else {}),
                "known": {**self.known, "per": self.per, "model": self.model},
                **({"notes": "; ".join(notes)} if notes else {})}
        new = with_factors(table, self.names, self.values, parameters=names, covariance=cov,
                           info=info)
        return replace(new, uncertainty=remaining_uncertainty(table.uncertainty, self.absorbed))

    def to_dict(self) -> dict[str, Any]:
        b = self.budget()
        lim = self.limited_by()
        rms = self.rms_residuals()
        return {
            "per": self.per, "model": self.model,
            "factors": {n: {"value": float(v), "sigma": b[n]["total"],
                            "sigma_noise": b[n]["noise"], "sigma_mass": b[n]["mass"],
                            "sigma_izz": b[n]["izz"], "sigma_table": b[n]["table"],
                            "limited_by": lim[n]}
                        for n, v in zip(self.names, self.values, strict=True)},
            "parameters": list(self.names),
            "covariance": self.cov.tolist(),
            "correlation": self.correlation.tolist(),
            "reference_count": self.reference_count,
            "absorbed_table_terms": list(self.absorbed),
            "table_terms": list(self.table_terms),
            "known": dict(self.known),
            "state0": dict(zip(("x", "y", "psi", "u", "v", "r"), self.state0.tolist(), strict=True)),
            "extras": dict(self.extras), "extras_sigma": dict(self.extras_sigma),
            "t0_s": self.t0, "n_poses": int(len(self.t)),
            "rms_residual_x_m": float(rms[0]), "rms_residual_y_m": float(rms[1]),
            "rms_residual_yaw_rad": float(rms[2]),
            "iterations": self.iterations, "converged": self.converged,
            "stages_s": list(self.stages), "min_eigenvalue": self.min_eigenvalue,
            **({"warnings": list(self.warnings)} if self.warnings else {}),
        }


def _kept_covariance(table: ThrustTable, kept: Sequence[str]) -> np.ndarray:
    cal = table.calibration
    idx = [cal.parameters.index(n) for n in kept]
    return cal.covariance[np.ix_(idx, idx)]


class CalibrationFit:
    """Residuals and Jacobian of the calibration problem on the poses up to a horizon."""

    def __init__(self, pose_t, pose, cmd_t, duty, table, names, extras, fixed, w, clamp, max_step):
        self.pose_t, self.pose, self.cmd_t, self.duty = pose_t, pose, cmd_t, duty
        self.table, self.names, self.extras, self.fixed = table, names, extras, fixed
        self.w, self.clamp, self.max_step = w, clamp, max_step
        self.ne = 6 + len(extras)

    def split(self, z):
        return z[:6], z[6:self.ne], z[self.ne:]

    def setup(self, z):
        s0, ex, f = self.split(z)
        table = with_factors(self.table, self.names, f)
        thrust, fjac = factor_jacobian(table, self.duty, self.names, self.clamp)
        params = dict(self.fixed)
        params.update({n: float(v) for n, v in zip(self.extras, ex, strict=True)})
        grid = make_grid(self.cmd_t, thrust, self.pose_t, self.max_step)
        return params, grid, fjac

    def evaluate(self, z):
        """``(cost, residuals (N, 3), cache)``; cost inf for a non-finite trajectory."""
        if not np.all(np.isfinite(z)) or np.any(self.split(z)[2] <= 0):
            return math.inf, None, None
        params, grid, fjac = self.setup(z)
        with np.errstate(all="ignore"):
            try:
                states = reference_states(z[:6], grid, params)
            except (OverflowError, ValueError):  # the scalar RK4 loop's math errors
                return math.inf, None, None
        if not np.all(np.isfinite(states)):
            return math.inf, None, None
        res = self.pose - states[grid.node_pos, :3]
        res[:, 2] = wrap_angle(res[:, 2])
        return float(np.sum(res**2 * self.w)), res, (params, grid, fjac, states)

    def jacobian(self, z, cache):
        """``(H (N, 3, 6+e+P), Jmi (N, 3, 2))``: d pose / d z and d pose / d (mass, izz)."""
        params, grid, fjac, states = cache
        with np.errstate(all="ignore"):
            _, phi = trajectory_stm(z[:6], None, None, self.pose_t, params,
                                    self.extras + ("mass", "izz"), grid=grid, states=states)
            Jf = output_sensitivity(states, grid, params, segment_jacobian(grid, fjac))
        H = np.concatenate([phi[:, :3, :self.ne], Jf], axis=-1)
        return H, phi[:, :3, self.ne:]


def normal_equations(H, w, res):
    """``(Lambda, lambda)``: ``sum H^T W H`` and ``sum H^T W r`` for H (N, 3, n), w (3,),
    r (N, 3)."""
    Lam = np.einsum("kin,i,kim->nm", H, w, H, optimize=True)
    lam = np.einsum("kin,i,ki->n", H, w, res, optimize=True)
    return Lam, lam


def _solve(Lam, lam, scale, mu):
    A = Lam * np.outer(scale, scale)
    d = np.sqrt(np.maximum(np.diag(A), 1e-300))
    An = A / np.outer(d, d) + mu * np.eye(len(d))
    y = np.linalg.lstsq(An, lam * scale / d, rcond=1e-14)[0]
    return y / d * scale


def _first_horizon(t_rel, pose, h0=5.0, min_poses=12):
    yaw = np.unwrap(pose[:, 2])
    turned = np.nonzero(np.abs(yaw - yaw[0]) > 1.0)[0]
    h = h0 if not turned.size else min(h0, float(t_rel[turned[0]]))
    return max(h, float(t_rel[min(min_poses, len(t_rel) - 1)]))


def _gauss_newton(fit: CalibrationFit, z, scale, *, reg: float, tol: float, tol_sigma: float | None,
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
        step = _solve(L, lam - wreg * (z - anchor), scale, mu)
        fstep = np.max(np.abs(step[fit.ne:]), initial=0.0)
        if fstep > 0.2:  # no factor moves by more than 0.2 per step
            step *= 0.2 / fstep
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


def calibrate_thrust(pose_t, pose, cmd_t, duty_pct, table: ThrustTable, *, mass_kg: float,
                     izz_kgm2: float, mass_sigma_kg: float = 0.0, izz_sigma_kgm2: float = 0.0,
                     per: str = "thruster", model: str = "ideal", arm_m: float = ARM_M,
                     sigma_pos_m: float = 0.01, sigma_yaw_rad: float = math.radians(1.0),
                     clamp: bool = False, tol: float = 1e-8, max_iter: int = 30,
                     horizon0_s: float | None = 5.0,
                     max_step: float = DEFAULT_MAX_STEP_S) -> ThrustCalibrationResult:
    """Estimate the in-situ factors of ``table`` from a run of a body of known m and Izz.

    Args:
        pose_t: (N,) pose times, s (t0 = pose_t[0]); pose: (N, 3) x, y (m), yaw (rad).
        cmd_t, duty_pct: (Nc,), (Nc, 4) commands (duty percent, 0 = closed), held.
        table: the thrust table (its coefficients are kept; factors it already has are
            the start, and those not estimated are kept with their covariance).
        mass_kg, izz_kgm2: the known body; ``*_sigma_*``: their standard uncertainties.
        per: ``thruster``, ``nozzles`` or ``both`` (see the module doc).
        model: ``ideal``, ``friction`` or ``friction+tilt`` (nuisance parameters).
        sigma_pos_m, sigma_yaw_rad: pose noise.
        tol: largest scaled correction at convergence; max_iter: per stage.
        horizon0_s: first horizon of the growing-horizon start (None: all at once).

    Raises UserError for a run that cannot separate the factors (see the module doc).
    """
    if model not in MODEL_EXTRAS:
        raise UserError(f"--model must be one of {', '.join(MODEL_EXTRAS)}, got {model!r}")
    for what, v in (("mass", mass_kg), ("Izz", izz_kgm2)):
        if not (math.isfinite(v) and v > 0):
            raise UserError(f"the known {what} must be positive, got {v:g}")
    for what, v in (("mass sigma", mass_sigma_kg), ("Izz sigma", izz_sigma_kgm2)):
        if not (math.isfinite(v) and v >= 0):
            raise UserError(f"the known {what} must be >= 0, got {v:g}")
    pose_t = np.asarray(pose_t, float)
    pose = np.asarray(pose, float)
    cmd_t = np.asarray(cmd_t, float)
    duty = np.asarray(duty_pct, float)
    if len(pose_t) < 10:
        raise UserError(f"{len(pose_t)} poses are too few to calibrate thrust")
    names, ref = factor_names(per, duty, cmd_t, float(pose_t[-1]))
    extras = MODEL_EXTRAS[model]
    fixed = {"mass": float(mass_kg), "izz": float(izz_kgm2), "arm": float(arm_m)}
    fixed.update({k: 0.0 for k in ("ct", "cr", "kb", "ax", "ay") if k not in extras})
    w = np.array([sigma_pos_m**-2, sigma_pos_m**-2, sigma_yaw_rad**-2])
    f0 = np.array([table.channel_factors(N_CHANNELS)[int(n.split(".")[1]) - 1]
                   if n.startswith("efficiency.") else table.nozzle_factor(int(n.split(".")[1]))
                   for n in names])
    cal = table.calibration
    kept = tuple(p for p in (cal.parameters if cal is not None else ()) if p not in names)
    base = with_factors(table, (), ())  # factor values as the table has them, no covariance
    z = np.concatenate([pose[0], np.zeros(3), np.zeros(len(extras)), f0])
    scale = np.concatenate([np.ones(6), [PARAM_SCALE[e] for e in extras], np.ones(len(names))])
    full = CalibrationFit(pose_t, pose, cmd_t, duty, base, names, extras, fixed, w, clamp, max_step)
    ne = full.ne

    # separability, checked at the start (structure does not depend on the estimate)
    def check(z, cache) -> float:
        H, _ = full.jacobian(z, cache)
        Lam, _ = normal_equations(H, w, np.zeros((len(pose_t), 3)))
        M = marginal_information(Lam, ne)
        lam_min, which = confounded(M, names)
        if lam_min < MIN_EIGENVALUE:
            raise UserError(_describe_confounding(which, lam_min))
        worst, which = worst_combination(M, names)
        if worst > MAX_COMBINATION_SIGMA:
            raise UserError(_describe_confounding(which, lam_min, worst))
        return lam_min

    cost, res, cache = full.evaluate(z)
    if not math.isfinite(cost):
        raise UserError("the start gives a non-finite trajectory (check --mass and --izz)")
    check(z, cache)

    t_rel = pose_t - pose_t[0]
    span = float(t_rel[-1])
    h = span if horizon0_s is None or horizon0_s <= 0 else _first_horizon(t_rel, pose, horizon0_s)
    stats = {"iterations": 0}
    stages: list[float] = []
    while True:
        last = h >= 0.75 * span
        if last:
            h = span
        keep = t_rel <= h + 1e-9
        fit = full if last else CalibrationFit(pose_t[keep], pose[keep], cmd_t, duty, base, names, extras,
                                     fixed, w, clamp, max_step)
        stages.append(h)
        z, converged, cost, res, cache = _gauss_newton(
            fit, z, scale, reg=0.0 if last else START_PRIOR, tol=tol if last else 0.0,
            tol_sigma=None if last else 0.1, max_iter=max_iter, stats=stats)
        if last:
            break
        h = 2 * h
    # covariance at the estimate
    H, Jmi = full.jacobian(z, cache)
    Lam, _ = normal_equations(H, w, res)
    lam_min = check(z, cache)
    cov_all = safe_inverse(Lam)
    if not np.all(np.isfinite(cov_all[ne:, ne:])):
        raise UserError(_describe_confounding(names, 0.0))
    b_mi = np.einsum("kin,i,kip->np", H, w, Jmi, optimize=True)
    S_mi = cov_all @ b_mi
    sl = slice(ne, None)
    Sm, Si = S_mi[sl, 0:1], S_mi[sl, 1:2]
    cov_mass = Sm @ Sm.T * mass_sigma_kg**2
    cov_izz = Si @ Si.T * izz_sigma_kgm2**2
    # the table's own uncertainty, without the terms the factors absorb
    absorbed = absorbed_terms(table, names)
    work = with_factors(table, names, z[ne:],
                        parameters=kept,
                        covariance=_kept_covariance(table, kept) if kept else None)
    sens = thrust_sensitivity(work, duty, clamp=clamp)
    keepc = [i for i, n in enumerate(sens.names) if n not in absorbed]
    table_terms = tuple(sens.names[i] for i in keepc)
    cov_table = np.zeros((len(names), len(names)))
    kept_cross = np.zeros((len(names), len(kept))) if kept else None
    if keepc:
        params, grid, _, states = cache
        J = output_sensitivity(states, grid, params,
                               segment_jacobian(grid, sens.jacobian[..., keepc]))
        Pc = sens.covariance[np.ix_(keepc, keepc)]
        b = np.einsum("kin,i,kip->np", H, w, J, optimize=True)
        S = (cov_all @ b)[sl]
        cov_table = S @ Pc @ S.T
        if kept:
            idx = [table_terms.index(n) for n in kept]
            # errors as stated - true: a kept factor stated too high makes the fit
            # lower the estimated ones (the factors' error is -S times the kept error)
            kept_cross = -(S @ Pc)[:, idx]
    cov_noise = cov_all[sl, sl]
    cov = cov_noise + cov_mass + cov_izz + cov_table
    ex_sig = np.sqrt(np.maximum(np.diag(cov_all)[6:ne], 0.0))
    result = ThrustCalibrationResult(
        names, z[ne:].copy(), 0.5 * (cov + cov.T), cov_noise, cov_mass, cov_izz,
        0.5 * (cov_table + cov_table.T), table_terms, absorbed, ref, per, model, z[:6].copy(),
        {e: float(v) for e, v in zip(extras, z[6:ne], strict=True)},
        {e: float(s) for e, s in zip(extras, ex_sig, strict=True)},
        float(pose_t[0]), pose_t, res, stats["iterations"], converged, stages, lam_min,
        {"mass_kg": float(mass_kg), "mass_sigma_kg": float(mass_sigma_kg),
         "izz_kgm2": float(izz_kgm2), "izz_sigma_kgm2": float(izz_sigma_kgm2)},
        kept_cross, kept)
    result.warnings = residual_warnings(result.rms_residuals(), sigma_pos_m, sigma_yaw_rad)
    if not converged:
        result.warnings.append(f"not converged after {stats['iterations']} iterations")
    for n, s in zip(names, result.sigma, strict=True):
        if s > 0.1:
            result.warnings.append(f"{n} is poorly determined (sigma {s:.2g}): the run hardly "
                                   "excites it")
    result.warnings += factor_warnings(names, result.values)  # 315 %: the wrong body?
    return result


def calibrate_run(run, table: ThrustTable, **kwargs) -> ThrustCalibrationResult:
    """:func:`calibrate_thrust` on a :class:`common.runfolder.Run` (commands.csv needed:
    a run that gives thrusts in newtons has no duty for the table's factors)."""
    if run.duty_pct is None:
        raise UserError(f"{run.path}: the run gives thrusts (thrusts.csv), not commands: "
                        "calibrating a thrust table needs commands.csv")
    return calibrate_thrust(run.pose_t, run.pose, run.cmd_t, run.duty_pct, table, **kwargs)
