"""One EKF step on plain arrays: propagation, prediction and the pose update.

The lean kernels behind every run of the filter (:func:`estimator.filters.loop.run_filter`,
the live estimator): tens of thousands of pose updates per second, the 3x3 algebra of the
pose update in closed form.

Physics: :mod:`estimator.plant.model` (compiled for the filter's parameter set by
:class:`estimator.plant.propagate.AugmentedPlant`: one scalar stage function per RK4 stage giving
the derivative and the Jacobian entries); the transition matrix is assembled from the four
stage Jacobians (:func:`estimator.plant.propagate.propagate_stm`), the same RK4 as
:func:`estimator.plant.propagate.rk4_stm`, one step per zero-order-hold segment (segments split
at every pose time and every command switch, and at ``max_step_s``).

Filter conventions (SI units throughout):

- prediction: ``P <- Phi P Phi^T + Q dt`` with ``Q = diag(q_psd)`` the continuous
  process-noise spectral density (units^2/s, e.g. kg^2/Hz for the mass);
- measurement ``(x, y, psi)`` with ``H = [I3 0]``; yaw residual wrapped to [-pi, pi),
  the state yaw stays continuous;
- update: Joseph form ``P <- (I-KH) P (I-KH)^T + K R K^T``, symmetrised every 16th update;
- underweighting (Zanetti, DeMars & Bishop 2010): when ``alpha > 0`` and the
  largest eigenvalue of ``R^-1/2 H P H^T R^-1/2`` exceeds ``uw_trigger`` (the
  predicted measurement uncertainty dominates R in some direction), the gain uses
  ``S = (1 + alpha) H P H^T + R``; otherwise the plain ``S = H P H^T + R``;
- parameter form: with ``inv`` the update corrects 1/m and 1/Izz (:func:`inverse_correction`);
- a tracked frame off the centre of mass: :func:`_update_offset`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from functools import cache

import numpy as np

from estimator.filters.config import INV_IDX, NZ, EkfConfig, _known_plant
from estimator.plant.model import ALL_EFFECTS, jacobian_pattern, scalar_stage
from estimator.plant.propagate import AugmentedPlant, propagate_stm

TWO_PI = 2.0 * math.pi
_dot = np.dot
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
    """How the pose measurement sees the centre of mass's offset: None when the
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

