"""Extended Kalman filter on the augmented state ``z = (x, y, psi, u, v, r, m, Izz)``.

Two implementations of one filter:

- plain array functions (:func:`propagate`, :func:`ekf_predict`, :func:`ekf_update`,
  :func:`run_ekf`): the lean path used for live estimation and the ``estimate batch
  --method ekf|ls-ekf`` command (tens of thousands of pose updates per second);
- :class:`TpodsEKF`, a filterpy ``ExtendedKalmanFilter`` whose ``predict_x`` runs the
  same nonlinear propagation and sets ``F`` to the analytic transition matrix, with an
  angle-wrapping residual and filterpy's Joseph-form update (:func:`run_filterpy`): the
  public, tested adapter and the tests' reference, in
  :mod:`estimator.filters.filterpy_adapter` (imported from here on first use, so that the
  lean path does not load filterpy and scipy).

Physics: :mod:`estimator.plant.model` (compiled for the filter's parameter set by
:class:`estimator.plant.propagate.AugmentedPlant`: one scalar stage function per RK4 stage giving
the derivative and the Jacobian entries); the transition matrix is assembled from the four
stage Jacobians (:func:`estimator.plant.propagate.propagate_stm`), the same RK4 as
:func:`estimator.plant.propagate.rk4_stm`, one step per zero-order-hold segment (segments split
at every pose time and every command switch, and at ``max_step_s``). :func:`run_filter` is
the loop for any parameter set (the extended filter of :mod:`estimator.filters.ekf_ext` too).

Filter conventions (SI units throughout):

- prediction: ``P <- Phi P Phi^T + Q dt`` with ``Q = diag(q_psd)`` the continuous
  process-noise spectral density (units^2/s, e.g. kg^2/Hz for the mass);
- measurement ``(x, y, psi)`` with ``H = [I3 0]``; yaw residual wrapped to [-pi, pi),
  the state yaw stays continuous;
- update: Joseph form ``P <- (I-KH) P (I-KH)^T + K R K^T``, symmetrised every 16th update;
- underweighting (Zanetti, DeMars & Bishop 2010): when ``alpha > 0`` and the
  largest eigenvalue of ``R^-1/2 H P H^T R^-1/2`` exceeds ``uw_trigger`` (the
  predicted measurement uncertainty dominates R in some direction), the gain uses
  ``S = (1 + alpha) H P H^T + R``; otherwise the plain ``S = H P H^T + R``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import cache

import numpy as np

from estimator.plant.model import ALL_EFFECTS, ARM_M, jacobian_pattern, scalar_stage, wrench
from estimator.plant.propagate import AugmentedPlant, propagate_stm, segment_thrust, zoh_segments

STATE_NAMES = ("x", "y", "psi", "u", "v", "r", "mass", "izz")
STATE_UNITS = ("m", "m", "rad", "m/s", "m/s", "rad/s", "kg", "kg m^2")
NX = 8
NZ = 3
TWO_PI = 2.0 * math.pi
_dot = np.dot
PARAM_FORMS = ("inverse", "direct")
INV_IDX = (6, 7)
"""Indices of mass and Izz in the 8-state filter (corrected as 1/m and 1/Izz)."""
NIS_BLOCK = 120
"""Updates per block of :attr:`EkfResult.nis_block_excess` (1 s at 120 Hz)."""
MIN_INV_RATIO = 0.05
"""1/m and 1/Izz must stay positive: one update may shrink either at most to this fraction
(m or Izz at most 20x larger); the correction is cut there, never elsewhere. A far start
needs the room (from 1 +/- 1 kg a 2.4 kg module asks for b < 0 at about 1 s; made as an
ordinary additive step there instead, m overshot to 18 kg and ended 10 sigma off); a
bound on the other side distorts the update too (a 2x bound left Izz 20 sigma off after
the first torque pulse). Data the model cannot explain (commands all 30 ms late) can
still drive m up by this factor per update until it overflows: diverged, as before."""


@cache
def _eye(n: int) -> np.ndarray:
    return np.eye(n)


@cache
def _h(n: int) -> np.ndarray:
    return np.eye(NZ, n)

def _known_plant(known, arm_m: float = ARM_M) -> AugmentedPlant:
    ct, cr, kb, ax, ay = known
    return AugmentedPlant.of(("mass", "izz"), {"arm": arm_m, "ct": ct, "cr": cr, "kb": kb,
                                               "ax": ax, "ay": ay})


# --------------------------------------------------------------------------------------
# Configuration


@dataclass(frozen=True)
class EkfConfig:
    """Filter settings (SI units).

    Attributes:
        x0: (8,) initial mean (x m, y m, psi rad, u m/s, v m/s, r rad/s, m kg, Izz kg m^2).
        sigma0: (8,) initial standard deviations, same units.
        q_psd: (8,) process-noise spectral density per state, units^2/s.
        sigma_meas: (3,) measurement standard deviations (m, m, rad).
        underweight: alpha of the underweighted update (0 = off).
        uw_trigger: underweighting is active while the largest eigenvalue of
            R^-1/2 H P H^T R^-1/2 exceeds this.
        max_step_s: longest RK4 step of the propagation, s.
        arm_m, ct, cr, kb, ax, ay: known plant terms (see :mod:`estimator.plant.model`).
        param_form: ``"inverse"`` (default): the measurement update corrects 1/m and 1/Izz
            (:func:`inverse_correction`); ``"direct"``: it corrects m and Izz (the paper's
            filter, and this toolkit's before issue 17).
    """

    x0: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 5e-3)
    sigma0: tuple[float, ...] = (0.1, 0.1, math.radians(5.0), 0.1, 0.1, math.radians(2.0),
                                 1.0, 2e-3)
    q_psd: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1e-4, 0.0)
    sigma_meas: tuple[float, float, float] = (0.01, 0.01, math.radians(1.0))
    underweight: float = 0.0
    uw_trigger: float = 1.0
    max_step_s: float = 0.01
    arm_m: float = ARM_M
    ct: float = 0.0
    cr: float = 0.0
    kb: float = 0.0
    ax: float = 0.0
    ay: float = 0.0
    param_form: str = "inverse"

    def __post_init__(self):
        for name, n in (("x0", NX), ("sigma0", NX), ("q_psd", NX), ("sigma_meas", NZ)):
            v = getattr(self, name)
            if len(v) != n:
                raise ValueError(f"{name} needs {n} values, got {len(v)}")
        if any(s <= 0 for s in self.sigma_meas):
            raise ValueError("measurement sigmas must be positive")
        if any(q < 0 for q in self.q_psd) or any(s < 0 for s in self.sigma0):
            raise ValueError("process noise and initial sigmas must be non-negative")
        if self.underweight < 0:
            raise ValueError("underweighting alpha must be >= 0")
        if self.max_step_s <= 0:
            raise ValueError("max_step_s must be positive")
        if self.param_form not in PARAM_FORMS:
            raise ValueError(f"param_form must be one of {', '.join(PARAM_FORMS)}")
        object.__setattr__(self, "_inv", INV_IDX if self.param_form == "inverse" else ())
        object.__setattr__(self, "_q_nz", tuple((i, float(q)) for i, q in enumerate(self.q_psd)
                                               if q))
        object.__setattr__(self, "_plant", _known_plant(self.known, self.arm_m))

    @property
    def plant(self) -> AugmentedPlant:
        """The filter's model: mass and Izz estimated, the known terms fixed."""
        return self._plant

    @property
    def P0(self) -> np.ndarray:
        return np.diag(np.square(self.sigma0))

    @property
    def R(self) -> np.ndarray:
        return np.diag(np.square(self.sigma_meas))

    @property
    def known(self) -> tuple[float, ...]:
        """(ct, cr, kb, ax, ay)."""
        return (self.ct, self.cr, self.kb, self.ax, self.ay)

    def with_(self, **kw) -> EkfConfig:
        return replace(self, **kw)


PAPER = EkfConfig()
"""The paper's EKF setting: 1e-4 kg^2/Hz on mass, its initial mean/std and 1 cm / 1 deg."""

PRESETS = {"paper": PAPER,
           "no-process-noise": PAPER.with_(q_psd=(0.0,) * NX)}


def parse_state_values(text: str, what: str = "value") -> dict[int, float]:
    """Parse ``name=value,...`` (names from STATE_NAMES, ``m`` for mass) into {index: value}."""
    alias = {"m": "mass", "i": "izz", "yaw": "psi"}
    out: dict[int, float] = {}
    for part in filter(None, (p.strip() for p in text.split(","))):
        if "=" not in part:
            raise ValueError(f"expected NAME={what}, got {part!r}")
        k, v = (s.strip() for s in part.split("=", 1))
        k = alias.get(k.lower(), k.lower())
        if k not in STATE_NAMES:
            raise ValueError(f"unknown state {k!r}; choose from {', '.join(STATE_NAMES)}")
        try:
            val = float(v)
        except ValueError:
            raise ValueError(f"{k}: not a number: {v!r}") from None
        if not math.isfinite(val):
            raise ValueError(f"{k}: must be finite")
        out[STATE_NAMES.index(k)] = val
    return out


# --------------------------------------------------------------------------------------
# Propagation: the plant of :mod:`estimator.plant.model`, RK4 of :mod:`estimator.plant.propagate`


def filter_plant(names: Sequence[str] = ("mass", "izz"), fixed: Mapping[str, float] | None = None
                 ) -> AugmentedPlant:
    """The filter's model: estimated parameters ``names``, the others at ``fixed``."""
    return AugmentedPlant.of(names, fixed)


_JAC_POS = jacobian_pattern(ALL_EFFECTS, ("mass", "izz"))
"""Entries of the 8-state Jacobian with every effect present (what :data:`_rhs_jac` appends)."""
_rhs_jac = scalar_stage(ALL_EFFECTS, ("mass", "izz"))
"""The 8-state stage function with every effect compiled in (tests compare it to the model)."""


def propagate(z, seg_dt, seg_w, known=(0.0, 0.0, 0.0, 0.0, 0.0), max_step_s: float = 0.01):
    """Propagate the 8-state augmented state and its transition matrix over hold segments
    (:func:`estimator.plant.propagate.propagate_stm` with the known terms ``(ct, cr, kb, ax, ay)``).

    Returns ``(z_end (8,), Phi (8, 8))``.
    """
    return propagate_stm(z, seg_dt, seg_w, _known_plant(known), max_step_s)


# --------------------------------------------------------------------------------------
# Predict / update on plain arrays


def ekf_predict(z, P, seg_dt, seg_w, cfg: EkfConfig):
    """EKF prediction over hold segments. Returns ``(z (n,), P (n, n), Phi (n, n))``."""
    return _predict(z, P, seg_dt, seg_w, cfg.plant, cfg._q_nz, cfg.max_step_s)


def _predict(z, P, seg_dt, seg_w, plant: AugmentedPlant, q_nz, max_step_s: float,
             q_per_step: bool = False):
    """``P <- Phi P Phi^T + diag(q) dt``, ``q_nz`` the non-zero ``(index, q)``; with
    ``q_per_step`` the noise is added after every RK4 step instead of once."""
    if q_per_step and q_nz:
        z1, phis, hs = propagate_stm(z, seg_dt, seg_w, plant, max_step_s, per_step=True)
        P1 = P
        for phi, h in zip(phis, hs, strict=True):
            P1 = _dot(_dot(phi, P1), phi.T)
            for i, q in q_nz:
                P1[i, i] += q * h
        return z1, P1, None
    z1, phi = propagate_stm(z, seg_dt, seg_w, plant, max_step_s)
    P1 = _dot(_dot(phi, P), phi.T)
    if q_nz:
        dt = float(sum(seg_dt))
        for i, q in q_nz:
            P1[i, i] += q * dt
    return z1, P1, phi


def wrap_residual(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Measurement residual ``a - b`` with the yaw component wrapped to [-pi, pi); works on columns."""
    d = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
    d[2] = (d[2] + math.pi) % TWO_PI - math.pi
    return d


def _max_eig_sym3(a, b, c, d, e, f) -> float:
    """Largest eigenvalue of the symmetric 3x3 [[a, d, e], [d, b, f], [e, f, c]] (closed form)."""
    p1 = d * d + e * e + f * f
    q = (a + b + c) / 3.0
    p2 = (a - q) ** 2 + (b - q) ** 2 + (c - q) ** 2 + 2.0 * p1
    if p2 <= 1e-300:
        return q
    p = math.sqrt(p2 / 6.0)
    ba, bb, bc = (a - q) / p, (b - q) / p, (c - q) / p
    bd, be, bf = d / p, e / p, f / p
    r = 0.5 * (ba * (bb * bc - bf * bf) - bd * (bd * bc - bf * be) + be * (bd * bf - bb * be))
    r = -1.0 if r < -1.0 else (1.0 if r > 1.0 else r)
    return q + 2.0 * p * math.cos(math.acos(r) / 3.0)


def uw_ratio(P: np.ndarray, R: np.ndarray) -> float:
    """Largest eigenvalue of ``R^-1/2 H P H^T R^-1/2`` (H = [I3 0]), the underweighting trigger.

    Only the diagonal of R is used (R is diagonal in this filter).
    """
    w = [1.0 / math.sqrt(R[i, i]) for i in range(NZ)]
    (a, d, e), (_, b, f), (_, _, c) = P[:NZ, :NZ].tolist()
    return _max_eig_sym3(a * w[0] * w[0], b * w[1] * w[1], c * w[2] * w[2], d * w[0] * w[1],
                         e * w[0] * w[2], f * w[1] * w[2])


def _inv_sym3(a, b, c, d, e, f):
    """Inverse of the symmetric 3x3 [[a, d, e], [d, b, f], [e, f, c]] as nested lists."""
    A = b * c - f * f
    B = e * f - d * c
    C = d * f - b * e
    det = a * A + d * B + e * C
    D = a * c - e * e
    E = d * e - a * f
    F = a * b - d * d
    k = 1.0 / det
    return [[A * k, B * k, C * k], [B * k, D * k, E * k], [C * k, E * k, F * k]]


def inverse_correction(z_prior, z, P, idx=INV_IDX) -> None:
    """Turn an update of m and Izz into the update of 1/m and 1/Izz, in place.

    Why: the thrust terms of the plant are ``F / m`` and ``Mz / Izz``, linear in ``b = 1/m``
    and ``c = 1/Izz``; with the yaw known the poses are linear in (initial state, b, c), so
    a filter on (state, b, c) is (nearly) a linear Kalman filter, whatever its start. The
    filter keeps m, Izz and their covariance (what every caller reads); the prediction is
    the same in either form (the parameters are constant over it, so the covariance maps
    through the fixed Jacobian ``dm/db = -m^2``). Only the update differs: the correction
    ``dm`` of the ordinary update becomes ``db = -dm / m^2``, so
    ``m_new = m / (1 - dm / m)``, and the covariance rows and columns of m are rescaled by
    ``(m_new / m)^2`` (the Jacobian at the new mean). Same for Izz. ``b_new / b`` is kept
    at or above :data:`MIN_INV_RATIO` (b stays positive).

    Args:
        z_prior: the state before the update (its m and Izz). z, P: after the ordinary
            update (modified). idx: indices of the parameters to treat.
    """
    g = []
    for i in idx:
        old = float(z_prior[i])
        if not old > 0.0:
            g.append(1.0)
            continue
        ratio = 1.0 - (float(z[i]) - old) / old  # b_new / b_old
        if not ratio >= MIN_INV_RATIO:  # (NaN too) see MIN_INV_RATIO
            ratio = MIN_INV_RATIO
        z[i] = old / ratio
        g.append(1.0 / (ratio * ratio))
    if len(idx) == 2 and idx[1] == idx[0] + 1:  # the usual case: one slice each way
        a = idx[0]
        P[a:a + 2, :] *= np.array(g)[:, None]
        P[:, a:a + 2] *= g
    else:
        for i, gi in zip(idx, g, strict=True):
            P[i, :] *= gi
            P[:, i] *= gi


def ekf_update(z, P, meas, cfg: EkfConfig, R: np.ndarray | None = None,
               symmetrize: bool = True):
    """Joseph-form measurement update with the optional underweighting.

    Args:
        z: (8,) predicted state. P: (8, 8) predicted covariance.
        meas: (3,) measured x (m), y (m), yaw (rad, may be wrapped).
        cfg: the filter settings. R: (3, 3) diagonal measurement covariance (default cfg.R).
        symmetrize: replace P by (P + P^T)/2 afterwards (:func:`run_ekf` does it every
            16th update; the Joseph form is symmetric up to rounding).

    Returns:
        ``(z, P, info)`` with ``info = (nis, triggered)``: the normalised innovation
        squared (with the plain S) and whether underweighting was active.
    """
    return _update(z, P, meas, cfg.R if R is None else R, cfg.underweight, cfg.uw_trigger,
                   symmetrize, cfg._inv)


def _update(z, P, meas, R, underweight: float, uw_trigger: float, symmetrize: bool = True,
            inv=()):
    """:func:`ekf_update` for any state size n >= 3 (H = [I3 0]); ``inv``: indices of the
    parameters corrected in inverse form (:func:`inverse_correction`)."""
    rd = R.diagonal()
    r0, r1, r2 = rd.tolist()
    (a, d, e), (_, b, f), (_, _, c) = P[:NZ, :NZ].tolist()
    zl = z[:NZ].tolist()
    y0 = meas[0] - zl[0]
    y1 = meas[1] - zl[1]
    y2 = (meas[2] - zl[2] + math.pi) % TWO_PI - math.pi
    si = _inv_sym3(a + r0, b + r1, c + r2, d, e, f)
    nis = (y0 * (si[0][0] * y0 + si[0][1] * y1 + si[0][2] * y2)
           + y1 * (si[1][0] * y0 + si[1][1] * y1 + si[1][2] * y2)
           + y2 * (si[2][0] * y0 + si[2][1] * y1 + si[2][2] * y2))
    triggered = False
    if underweight > 0.0:
        w0, w1, w2 = 1.0 / math.sqrt(r0), 1.0 / math.sqrt(r1), 1.0 / math.sqrt(r2)
        if _max_eig_sym3(a * w0 * w0, b * w1 * w1, c * w2 * w2, d * w0 * w1, e * w0 * w2,
                         f * w1 * w2) > uw_trigger:
            triggered = True
            g = 1.0 + underweight
            si = _inv_sym3(g * a + r0, g * b + r1, g * c + r2, g * d, g * e, g * f)
    K = _dot(P[:, :NZ], np.array(si))
    z1 = z + _dot(K, np.array([y0, y1, y2]))
    A = _eye(len(z)) - _dot(K, _h(len(z)))
    P = _dot(_dot(A, P), A.T) + _dot(K * rd, K.T)
    if inv:
        inverse_correction(z, z1, P, inv)
    z = z1
    if symmetrize:
        P += P.T
        P *= 0.5
    return z, P, (nis, triggered)


def _offset_spec(plant: AugmentedPlant):
    """How the pose measurement sees the centre of mass's offset (issue 18): None when the
    tracked frame is the centre of mass (the fast update), else ``(ix, iy, cx, cy)``: the
    state indices of cx, cy when estimated (None when fixed) and their fixed values."""
    fixed = dict(plant.fixed)
    ix = 6 + plant.names.index("cx") if "cx" in plant.names else None
    iy = 6 + plant.names.index("cy") if "cy" in plant.names else None
    cx, cy = fixed.get("cx", 0.0), fixed.get("cy", 0.0)
    if ix is None and iy is None and cx == 0.0 and cy == 0.0:
        return None
    return ix, iy, cx, cy


def _update_offset(z, P, meas, R, off, inv=()):
    """Pose update when the tracked frame is off the centre of mass: ``h(x) = p - R(psi) c``
    (the states are the centre of mass's), linearised at the prior; Joseph form."""
    ix, iy, cx0, cy0 = off
    n = len(z)
    cx = z[ix] if ix is not None else cx0
    cy = z[iy] if iy is not None else cy0
    c, sn = math.cos(z[2]), math.sin(z[2])
    h = np.array([z[0] - (c * cx - sn * cy), z[1] - (sn * cx + c * cy), z[2]])
    H = np.zeros((NZ, n))
    H[0, 0] = H[1, 1] = H[2, 2] = 1.0
    H[0, 2] = sn * cx + c * cy
    H[1, 2] = -c * cx + sn * cy
    if ix is not None:
        H[0, ix], H[1, ix] = -c, -sn
    if iy is not None:
        H[0, iy], H[1, iy] = sn, -c
    y = np.asarray(meas, float) - h
    y[2] = (y[2] + math.pi) % TWO_PI - math.pi
    S = H @ P @ H.T + R
    Si = np.linalg.inv(S)
    nis = float(y @ Si @ y)
    K = P @ H.T @ Si
    z1 = z + K @ y
    A = np.eye(n) - K @ H
    P = A @ P @ A.T + K @ R @ K.T
    if inv:
        inverse_correction(z, z1, P, inv)
    P = 0.5 * (P + P.T)
    return z1, P, (nis, False)


# --------------------------------------------------------------------------------------
# Whole-run filtering


@dataclass
class EkfResult:
    """Output of a filter run over a pose history.

    Attributes:
        t: (N,) pose times, s.
        x: (N, 8) posterior means at the pose times (prior where no update was made).
        sigma: (N, 8) matching standard deviations.
        P: (8, 8) final covariance.
        updated: (N,) whether the pose was used.
        triggered: (N,) whether the underweighted update was active.
        nis: (N,) normalised innovation squared (NaN where not updated).
        cov: (N, 8, 8) covariances if requested, else None.
    """

    t: np.ndarray
    x: np.ndarray
    sigma: np.ndarray
    P: np.ndarray
    updated: np.ndarray
    triggered: np.ndarray
    nis: np.ndarray
    cov: np.ndarray | None = None
    extra: dict = field(default_factory=dict)

    @property
    def mass_kg(self) -> float:
        return float(self.x[-1, 6])

    @property
    def izz_kgm2(self) -> float:
        return float(self.x[-1, 7])

    @property
    def diverged(self) -> bool:
        """Non-physical parameters, a mass or Izz variance that is not positive (the covariance
        broke down), or a mean NIS over the last 10 % of updates above 10 (3 expected)."""
        if self.x[-1, 6] <= 0 or self.x[-1, 7] <= 0 or not np.all(np.isfinite(self.x[-1])):
            return True
        if not (self.P[6, 6] > 0 and self.P[7, 7] > 0 and np.all(np.isfinite(self.P))):
            return True
        tail = self.nis_tail_mean
        return bool(tail > 10.0)

    @property
    def nis_tail_mean(self) -> float:
        """Mean NIS over the last 10 % of updates (3 expected; NaN without updates)."""
        nis = self.nis[self.updated]
        if len(nis) == 0:
            return math.nan
        tail = nis[-max(1, len(nis) // 10):]
        tail = tail[~np.isnan(tail)]  # a filter that blew up: NaN
        return float(tail.mean()) if len(tail) else math.nan

    @property
    def inconsistent(self) -> bool:
        """The innovations at the end are larger than the filter's covariance allows: the
        mean NIS over the last 10 % of n updates exceeds ``max(4, chi2_0.999(3n) / n)``.

        A parameter sweep (300 runs, 0.3-8 kg, 0.5-5 mm poses, EKF from the paper's guess
        and LS+EKF) gave a largest tail mean of 3.6 among the 339 filters whose final m and
        Izz were inside 4 sigma, and above 4 for 61 of the 111 filters that ended more than
        4 sigma off without tripping :attr:`diverged`. Such an estimate's sigma is not
        trustworthy. Also true when :attr:`nis_block_excess` is above 1 (issue 17: a filter
        inconsistent on the way can end with a normal tail around a wrong value).
        """
        from scipy.stats import chi2

        n = max(1, int(self.updated.sum()) // 10)
        tail = self.nis_tail_mean
        if tail > max(4.0, float(chi2.ppf(0.999, 3 * n)) / n):
            return True
        return self.nis_block_excess > 1.0

    @property
    def nis_block_excess(self) -> float:
        """The largest mean NIS over blocks of :data:`NIS_BLOCK` consecutive updates,
        relative to its chi-square limit at a false-alarm rate of 1e-4 per run (Bonferroni
        over the blocks). Above 1: somewhere in the run the innovations were far larger
        than the covariance allowed, and a filter that was inconsistent once does not
        recover its consistency with constant parameters (it may end with a normal tail
        NIS but a collapsed covariance around a wrong value: seen in the issue-17 sweep,
        Izz 25 sigma off with a tail NIS of 4.8, after block means of 11-15). NaN without a
        full block."""
        from scipy.stats import chi2

        nis = self.nis[self.updated]
        nis = nis[~np.isnan(nis)]
        nb = len(nis) // NIS_BLOCK
        if nb < 1:
            return math.nan
        means = nis[:nb * NIS_BLOCK].reshape(nb, NIS_BLOCK).mean(axis=1)
        limit = float(chi2.isf(1e-4 / nb, 3 * NIS_BLOCK)) / NIS_BLOCK
        return float(means.max() / limit)

    def rmse(self, mass_kg: float, izz_kgm2: float, t_from: float | None = None) -> tuple[float, float]:
        """RMS error of m and Izz over every pose time (from ``t_from``), kg and kg m^2."""
        sel = slice(None) if t_from is None else self.t >= t_from
        e = self.x[sel, 6:8] - np.array([mass_kg, izz_kgm2])
        r = np.sqrt(np.mean(e**2, axis=0))
        return float(r[0]), float(r[1])


@dataclass
class Schedule:
    """Hold segments between consecutive pose times.

    ``seg_dt[k]`` and ``seg_w[k]`` list the segments from ``pose_t[k-1]`` to
    ``pose_t[k]`` (empty for k = 0).
    """

    pose_t: np.ndarray
    seg_dt: list[list[float]]
    seg_w: list[list[tuple[float, float, float]]]


def make_schedule(pose_t, cmd_t, thrust_n, arm_m: float = ARM_M) -> Schedule:
    """Split the pose intervals at command switches (thrust zero before the first command)."""
    pose_t = np.asarray(pose_t, dtype=float)
    events, cmd_idx, node_pos = zoh_segments(cmd_t, pose_t)
    w = wrench(segment_thrust(thrust_n, cmd_idx), arm_m).tolist()
    dts = np.diff(events).tolist()
    seg_dt: list[list[float]] = [[]]
    seg_w: list[list] = [[]]
    for k in range(1, len(pose_t)):
        a, b = int(node_pos[k - 1]), int(node_pos[k])
        seg_dt.append(dts[a:b])
        seg_w.append(w[a:b])
    return Schedule(pose_t, seg_dt, seg_w)


def initial_estimate(cfg: EkfConfig, x0, P0):
    """The filter's start ``(x (8,), P (8, 8))``: the given values or the setting's."""
    x = np.array(cfg.x0 if x0 is None else x0, dtype=float)
    P = cfg.P0 if P0 is None else np.array(P0, dtype=float)
    if x.shape != (NX,) or P.shape != (NX, NX):
        raise ValueError("x0 must be (8,) and P0 (8, 8)")
    return x, P


def run_ekf(pose_t, pose, cmd_t, thrust_n, cfg: EkfConfig = PAPER, x0=None, P0=None,
            use=None, keep_cov: bool = False, progress=None) -> EkfResult:
    """Filter a pose history with the lean EKF.

    Args:
        pose_t: (N,) increasing pose times, s (any spacing; dropped frames are gaps).
        pose: (N, 3) x (m), y (m), yaw (rad, wrapped or not).
        cmd_t, thrust_n: (Nc,), (Nc, 4) zero-order-hold thrusts, N.
        cfg: filter settings. x0, P0: initial mean (8,) and covariance (8, 8) at
            ``pose_t[0]`` (default from cfg).
        use: optional (N,) bool, which poses to update with (others: predict only).
        keep_cov: also return every covariance.
        progress: optional callable(k) called every 1000 poses.
    """
    sched = make_schedule(pose_t, cmd_t, thrust_n, cfg.arm_m)
    x, P = initial_estimate(cfg, x0, P0)
    h = run_filter(sched, pose, cfg.plant, x, P, cfg.R, cfg._q_nz, cfg.max_step_s,
                   cfg.underweight, cfg.uw_trigger, use, keep_cov, progress, inv=cfg._inv)
    return EkfResult(sched.pose_t.copy(), h.x, h.sigma, h.P, h.updated, h.triggered, h.nis,
                     h.cov)


@dataclass
class FilterHistory:
    """What :func:`run_filter` returns: means, sigmas, NIS and flags at every pose."""

    x: np.ndarray
    sigma: np.ndarray
    P: np.ndarray
    updated: np.ndarray
    triggered: np.ndarray
    nis: np.ndarray
    cov: np.ndarray | None


def run_filter(sched: Schedule, pose, plant: AugmentedPlant, x, P, R, q_nz=(),
               max_step_s: float = 0.01, underweight: float = 0.0, uw_trigger: float = 1.0,
               use=None, keep_cov: bool = False, progress=None, *, q_per_step: bool = False,
               stop_on_blowup: bool = False, inv=()) -> FilterHistory:
    """The EKF loop for any model (the one filter behind :func:`run_ekf` and the extended
    filter of :mod:`estimator.filters.ekf_ext`).

    Args:
        sched: hold segments between the poses (:func:`make_schedule`).
        pose: (N, 3) x, y (m), yaw (rad). plant: the model (:class:`AugmentedPlant`).
        x, P: (n,), (n, n) initial mean and covariance at the first pose.
        R: (3, 3) diagonal pose covariance. q_nz: non-zero process-noise densities as
            ``(state index, units^2/s)``. max_step_s: longest RK4 step.
        underweight, uw_trigger: the underweighted update (alpha 0 = off).
        use: optional (N,) bool, poses to update with (others: predict only).
        keep_cov: keep every covariance. progress: callable(k) every 1000 poses.
        q_per_step: add the process noise after every RK4 step (else once per interval).
        stop_on_blowup: a prediction that overflows ends the filter: NaN from there on.
        inv: state indices of mass and Izz to correct as 1/m and 1/Izz
            (:func:`inverse_correction`); empty: corrected directly.
    """
    pose = np.asarray(pose, dtype=float)
    n = len(sched.pose_t)
    nx = plant.n
    use = np.ones(n, bool) if use is None else np.asarray(use, bool)
    xs = np.empty((n, nx))
    sig = np.empty((n, nx))
    nis = np.full(n, np.nan)
    trig = np.zeros(n, bool)
    covs = np.empty((n, nx, nx)) if keep_cov else None
    meas = pose.tolist()
    off = _offset_spec(plant)
    if off is not None and underweight > 0:
        raise ValueError("underweighting is not built for a tracked frame off the centre of mass")
    for k in range(n):
        if k:
            if stop_on_blowup:
                with np.errstate(over="ignore", invalid="ignore"):
                    try:
                        x, P, _ = _predict(x, P, sched.seg_dt[k], sched.seg_w[k], plant, q_nz,
                                           max_step_s, q_per_step)
                    except (ValueError, OverflowError):  # the scalar stage's math.cos(inf)
                        x = np.full(nx, np.nan)
                if not (np.all(np.isfinite(x)) and np.all(np.isfinite(P))):
                    xs[k:] = np.nan
                    sig[k:] = np.nan
                    P = np.full((nx, nx), np.nan)
                    if keep_cov:
                        covs[k:] = np.nan
                    break
            else:
                x, P, _ = _predict(x, P, sched.seg_dt[k], sched.seg_w[k], plant, q_nz,
                                   max_step_s, q_per_step)
        if use[k]:
            if off is None:
                x, P, (nis[k], trig[k]) = _update(x, P, meas[k], R, underweight, uw_trigger,
                                                  (k & 15) == 0, inv)
            else:
                x, P, (nis[k], trig[k]) = _update_offset(x, P, meas[k], R, off, inv)
        xs[k] = x
        sig[k] = P.diagonal()
        if keep_cov:
            covs[k] = P
        if progress is not None and k % 1000 == 0:
            progress(k)
    np.sqrt(np.maximum(sig, 0.0), out=sig)
    return FilterHistory(xs, sig, P, use.copy(), trig, nis, covs)


# --------------------------------------------------------------------------------------
# Plausibility after a filter run (issue 16)

INFO_FRACTION = 0.5
"""A parameter whose final sigma is above this fraction of its initial sigma has learnt
(almost) nothing from the run: the estimate is mostly the starting guess, and the fit is
not called converged."""


def residual_rms(t, x, updated, pose, tail: float = 0.5) -> np.ndarray:
    """(3,) RMS of the post-update pose residuals (x, y m; yaw rad, wrapped) over the last
    ``tail`` of the updated poses (after the start-up transient)."""
    idx = np.flatnonzero(np.asarray(updated, bool))
    if len(idx) == 0:
        return np.full(3, math.nan)
    idx = idx[int(len(idx) * (1.0 - tail)):]
    d = np.asarray(pose, float)[idx] - np.asarray(x, float)[idx, :NZ]
    d[:, 2] = (d[:, 2] + math.pi) % TWO_PI - math.pi
    return np.sqrt(np.mean(d**2, axis=0))


def pose_scatter(t, pose) -> np.ndarray:
    """(3,) the poses' own noise level (x, y m; yaw rad): RMS of second differences of
    evenly spaced triples over sqrt(6) (white noise; motion adds ~a dt^2, negligible at
    mocap rates). NaN without such triples."""
    t = np.asarray(t, float)
    p = np.asarray(pose, float).copy()
    p[:, 2] = np.unwrap(p[:, 2])
    if len(t) < 3:
        return np.full(3, math.nan)
    h1, h2 = np.diff(t)[:-1], np.diff(t)[1:]
    even = np.abs(h2 - h1) <= 1e-6 * np.maximum(h1, h2)
    if not even.any():
        return np.full(3, math.nan)
    d2 = (p[2:] - 2.0 * p[1:-1] + p[:-2])[even]
    return np.sqrt(np.mean(d2**2, axis=0) / 6.0)


def filter_plausibility(t, x, sigma, updated, pose, sigma_meas, sigma0, seg_w,
                        names: Sequence[str] = ("mass", "izz"), first: int = 6
                        ) -> tuple[str, list[str], np.ndarray]:
    """What a filter's result says about itself, as batch least squares reports it.

    Args:
        t, x, sigma, updated: the filter's history (N,), (N, n), (N, n), (N,).
        pose: (N, 3) the measured poses. sigma_meas: (3,) the stated pose noise.
        sigma0: (n,) initial standard deviations. seg_w: per pose interval, the body
            wrenches (Fx, Fy, Mz) of its hold segments (:class:`Schedule`).
        names, first: the parameters and the state index of the first one.

    Returns:
        ``(no_info, warnings, rms)``: ``no_info`` is '' when every parameter learnt from
        the run, else which did not and why (no thrust, no net force, no torque, or a final
        sigma above :data:`INFO_FRACTION` of the initial one); ``warnings`` one line per
        post-update residual whose RMS is more than 10x off the stated noise, naming the
        likely causes (:func:`estimator.batch.least_squares.residual_warnings`: millimetres,
        degrees, the thrust table's unit, another body); ``rms`` the (3,) residual RMS.
        When the filter did not finish (NaN: it blew up, e.g. on poses in millimetres),
        the poses' own scatter (:func:`pose_scatter`) is compared with the stated noise
        instead.
    """
    # lazy: the batch module is needed only after a whole-run fit, not by the live filter
    from estimator.batch.least_squares import residual_warnings

    w = [wi for seg in seg_w for wi in seg]
    force = any(abs(a) > 0.0 or abs(b) > 0.0 for a, b, _ in w)
    torque = any(abs(c) > 0.0 for _, _, c in w)
    why = {}
    if not force and not torque:
        why = {n: "no thrust: every valve is closed in every command (or the thrust table "
                  "gives 0 N)" for n in names if n in ("mass", "izz")}
    else:
        if not force and "mass" in names:
            why["mass"] = "no net force (the thrusts cancel)"
        if not torque and "izz" in names:
            why["izz"] = "no torque (the commands never turn the module)"
    s0 = np.asarray(sigma0, float)
    s1 = np.asarray(sigma, float)[-1]
    for j, n in enumerate(names):
        i = first + j
        if n in why or not (s0[i] > 0 and math.isfinite(s0[i])) or not math.isfinite(s1[i]):
            continue  # (a filter that blew up is diverged, not uninformed)
        if not s1[i] <= INFO_FRACTION * s0[i]:  # NaN too
            why[n] = (f"little information: its sigma went from {s0[i]:.3g} to {s1[i]:.3g}, "
                      "the estimate is mostly the starting guess")
    no_info = ""
    if why:
        bad = list(why)
        no_info = (f"{', '.join(bad)} {'has' if len(bad) == 1 else 'have'} no information in "
                   f"this run: " + "; ".join(f"{n}: {why[n]}" for n in bad))
    rms = residual_rms(t, x, updated, pose)
    warnings = []
    if np.all(np.isfinite(rms)):
        warnings = [f"the filter's {line}" for line in
                    residual_warnings(rms, float(sigma_meas[0]), float(sigma_meas[2]))]
    else:
        sc = pose_scatter(t, pose)
        if np.all(np.isfinite(sc)):
            warnings = [f"the filter did not finish; the poses' own scatter: {line}" for line in
                        residual_warnings(sc, float(sigma_meas[0]), float(sigma_meas[2]))]
    return no_info, warnings, rms


# --------------------------------------------------------------------------------------
# Methods on a whole run: EKF alone, LS-initialised EKF

FILTER_METHODS = ("ekf", "ls-ekf")
LS_STARTS = ("reuse", "handoff")


@dataclass
class FilterEstimate:
    """Result of :func:`estimate_filter`: the filter run and, for ls-ekf, the batch fit."""

    method: str
    result: EkfResult
    ls: object | None = None
    ls_window_s: float | None = None
    ls_start: str | None = None
    no_information: str = ""
    """'' or which parameter learnt nothing from the run, and why (:func:`filter_plausibility`)."""
    warnings: list[str] = field(default_factory=list)
    """Post-update residuals far from the stated noise (:func:`filter_plausibility`)."""
    rms_residuals: np.ndarray | None = None

    @property
    def converged(self) -> bool:
        """Not diverged, and every parameter learnt from the run."""
        return not self.result.diverged and not self.no_information

    def to_dict(self) -> dict:
        r = self.result
        P = r.P
        # a diverged filter can end with a negative variance: no sigma then (NaN), and
        # ``diverged`` is True
        sm, si = (math.sqrt(v) if v > 0 and math.isfinite(v) else math.nan
                  for v in (float(P[6, 6]), float(P[7, 7])))
        d = {
            "method": self.method,
            "mass_kg": r.mass_kg, "mass_sigma_kg": sm,
            "izz_kgm2": r.izz_kgm2, "izz_sigma_kgm2": si,
            "corr_mass_izz": float(P[6, 7] / (sm * si)) if sm > 0 and si > 0 else None,
            "final_state": dict(zip(STATE_NAMES, r.x[-1].tolist(), strict=True)),
            "final_sigma": dict(zip(STATE_NAMES, r.sigma[-1].tolist(), strict=True)),
            "t0_s": float(r.t[0]), "t1_s": float(r.t[-1]), "n_poses": int(len(r.t)),
            "n_updates": int(r.updated.sum()),
            "nis_mean": float(np.nanmean(r.nis)) if r.updated.any() else None,
            "underweighted_updates": int(r.triggered.sum()),
            "diverged": r.diverged,
            "nis_tail_mean": r.nis_tail_mean if r.updated.any() else None,
            "inconsistent": r.inconsistent,
            "nis_block_excess": r.nis_block_excess if r.updated.any() else None,
            "converged": self.converged,
        }
        if self.no_information:
            d["message"] = "not converged: " + self.no_information
        if self.rms_residuals is not None:
            rx, ry, rw = (float(v) for v in self.rms_residuals)
            d.update({"rms_residual_x_m": rx, "rms_residual_y_m": ry, "rms_residual_yaw_rad": rw})
        if self.warnings:
            d["warnings"] = list(self.warnings)
        if self.ls is not None:
            d["ls_window_s"] = self.ls_window_s
            d["ls_start"] = self.ls_start
            d["ls"] = {"mass_kg": self.ls.mass_kg, "mass_sigma_kg": self.ls.mass_sigma_kg,
                       "izz_kgm2": self.ls.izz_kgm2, "izz_sigma_kgm2": self.ls.izz_sigma_kgm2,
                       "converged": self.ls.converged, "message": self.ls.message,
                       "n_poses": int(len(self.ls.t))}
        return d


def estimate_filter(pose_t, pose, cmd_t, thrust_n, method: str = "ekf", cfg: EkfConfig = PAPER,
                    x0=None, P0=None, ls_window_s: float = 20.0, ls_start: str = "reuse",
                    ls_kwargs: dict | None = None) -> FilterEstimate:
    """Run ``ekf`` or ``ls-ekf`` on one pose history.

    ``ls-ekf``: batch least squares (:func:`estimator.batch.least_squares.batch_ls`) on the poses of
    the first ``ls_window_s`` seconds gives the mean and full covariance at
    ``pose_t[0]``. ``ls_start="reuse"`` (the paper) then filters the whole run from
    there, so the window's poses are used twice (by the fit and by the filter) and the
    filter is over-confident; ``"handoff"`` propagates the fit through the window
    without updates and filters only the later poses, each pose used once.
    Raises ValueError for a bad method and UserError when the batch fit fails.
    """
    from common.errors import UserError

    if method not in FILTER_METHODS:
        raise ValueError(f"method must be one of {', '.join(FILTER_METHODS)}")
    if method == "ekf":
        x, P = initial_estimate(cfg, x0, P0)
        sched = make_schedule(pose_t, cmd_t, thrust_n, cfg.arm_m)
        # a filter that blows up (poses in mm, yaw in degrees) overflows: flagged diverged
        # and explained by the plausibility check, not numpy warnings on the terminal
        with np.errstate(over="ignore", invalid="ignore"):
            res = run_ekf(pose_t, pose, cmd_t, thrust_n, cfg, x, P)
        return _checked(FilterEstimate(method, res), pose, cfg, np.sqrt(np.diag(P)), sched)
    if ls_start not in LS_STARTS:
        raise ValueError(f"ls_start must be one of {', '.join(LS_STARTS)}")
    from estimator.batch.least_squares import batch_ls

    pose_t = np.asarray(pose_t, dtype=float)
    pose = np.asarray(pose, dtype=float)
    win = pose_t <= pose_t[0] + ls_window_s
    if win.sum() < 4:
        raise UserError(f"the LS window of {ls_window_s:g} s holds fewer than 4 poses")
    kw = {"sigma_pos_m": cfg.sigma_meas[0], "sigma_yaw_rad": cfg.sigma_meas[2],
          "fixed": {"arm": cfg.arm_m, "ct": cfg.ct, "cr": cfg.cr, "kb": cfg.kb, "ax": cfg.ax,
                    "ay": cfg.ay}}
    kw.update(ls_kwargs or {})
    ls = batch_ls(pose_t[win], pose[win], cmd_t, thrust_n, **kw)
    if not ls.converged:
        raise UserError(f"batch least squares on the first {ls_window_s:g} s did not converge "
                        f"({ls.message}); cannot start ls-ekf from it")
    if ls.z0[6] <= 0 or ls.z0[7] <= 0:
        raise UserError("batch least squares gave a non-physical start (mass or Izz <= 0)")
    if not np.all(np.isfinite(ls.cov)):
        # e.g. a window without any torque: Izz has no information, an infinite variance
        unknown = [lab for lab, sd in zip(ls.labels, ls.sigma, strict=True) if not math.isfinite(sd)]
        raise UserError(f"the first {ls_window_s:g} s do not determine {', '.join(unknown)} "
                        "(no information: infinite variance); lengthen --ls-window or use "
                        "--method ls")
    cov = 0.5 * (ls.cov + ls.cov.T)
    use = None if ls_start == "reuse" else ~win
    with np.errstate(over="ignore", invalid="ignore"):  # flagged, as above
        res = run_ekf(pose_t, pose, cmd_t, thrust_n, cfg, ls.z0, cov, use=use)
    # the information check of the filter is against the prior sigma (the LS start has
    # already refused a window without information)
    return _checked(FilterEstimate(method, res, ls, ls_window_s, ls_start), pose, cfg,
                    np.full(NX, math.inf), make_schedule(pose_t, cmd_t, thrust_n, cfg.arm_m))


def _checked(fe: FilterEstimate, pose, cfg: EkfConfig, sigma0, sched: Schedule
             ) -> FilterEstimate:
    """``fe`` with its plausibility (:func:`filter_plausibility`) filled in."""
    r = fe.result
    fe.no_information, fe.warnings, fe.rms_residuals = filter_plausibility(
        r.t, r.x, r.sigma, r.updated, pose, cfg.sigma_meas, sigma0, sched.seg_w)
    return fe


def initial_rates(pose_t, pose, span_s: float = 0.25) -> tuple[np.ndarray, np.ndarray]:
    """Body-frame velocities (u, v, r) at ``pose_t[0]`` from a straight-line fit of the poses.

    Fits x, y and the unwrapped yaw linearly over the first ``span_s`` seconds (at least 3
    poses). Returns ``(rates (3,), sigmas (3,))``: the fitted u, v (m/s) and r (rad/s), and
    the standard deviations of the fitted slopes from the fit residuals. Use it to start a
    filter on a run (or a window) that does not begin at rest.
    """
    t = np.asarray(pose_t, dtype=float)
    p = np.asarray(pose, dtype=float)
    n = max(3, int(np.searchsorted(t, t[0] + span_s, side="right")))
    n = min(n, len(t))
    if n < 3:
        return np.zeros(3), np.full(3, np.inf)
    tt = t[:n] - t[0]
    yaw = np.unwrap(p[:n, 2])
    X = np.column_stack([np.ones(n), tt])
    Y = np.column_stack([p[:n, 0], p[:n, 1], yaw])
    coef, *_ = np.linalg.lstsq(X, Y, rcond=None)
    res = Y - X @ coef
    dof = max(n - 2, 1)
    s2 = np.sum(res**2, axis=0) / dof
    var_slope = s2 * np.linalg.inv(X.T @ X)[1, 1]
    xd, yd, r = coef[1]
    c, s = math.cos(coef[0, 2]), math.sin(coef[0, 2])
    u = xd * c + yd * s
    v = -xd * s + yd * c
    sig_uv = math.sqrt(max(var_slope[0], var_slope[1]))
    return np.array([u, v, r]), np.array([sig_uv, sig_uv, math.sqrt(var_slope[2])])


def __getattr__(name: str):
    """``TpodsEKF`` and ``run_filterpy`` from :mod:`estimator.filters.filterpy_adapter`."""
    if name in ("TpodsEKF", "run_filterpy"):
        # lazy: filterpy imports scipy (~0.6 s), which neither the lean filter nor `tpods --help` needs
        from estimator.filters import filterpy_adapter

        return getattr(filterpy_adapter, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
