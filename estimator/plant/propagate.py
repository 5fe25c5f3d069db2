"""State and state-transition-matrix propagation under zero-order-hold thrusts.

The augmented state is ``z = (x, y, psi, u, v, r, theta)`` where ``theta`` holds the
estimated parameters named in ``names`` (a subset of ``model.PARAM_NAMES``, e.g.
``("mass", "izz")``) with ``theta_dot = 0``. Its transition matrix over a hold
segment is::

    Phi = [[Phi_ss, Phi_stheta],
           [0,      I         ]]

with ``d/dt Phi_ss = J_s Phi_ss`` and ``d/dt Phi_stheta = J_s Phi_stheta + J_theta``
(Eqs. 16-17 of the paper), integrated jointly with the state by RK4.

Everything broadcasts over leading dimensions, so one call can propagate every
segment of a trajectory at once (batch least squares: leading dim = segments, each
started from its reference state) or every run of a Monte Carlo (leading dim = runs).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from estimator.plant.model import (
    ARM_M,
    PARAM_NAMES,
    active_effects,
    array_function,
    jacobian_pattern,
    scalar_stage,
    wrench,
)
from estimator.plant.segments import segment_thrust, zoh_segments  # noqa: F401  (re-exported)

ParamDict = Mapping[str, "float | np.ndarray"]


def _stage_function(params: ParamDict, names: tuple[str, ...]):
    """The compiled rates-and-Jacobian function of the effects ``params`` and ``names`` need
    (:func:`model.active_effects`: an effect whose parameters are all zero and not estimated
    costs nothing), its pattern split into state and parameter columns."""
    eff = active_effects(params, names)
    pattern = jacobian_pattern(eff, names)
    cols_s = [(k, i, j) for k, (i, j) in enumerate(pattern) if j < 6]
    cols_t = [(k, i, j - 6) for k, (i, j) in enumerate(pattern) if j >= 6]
    return array_function(eff, names), cols_s, cols_t


STM_BLOCK = 1024
"""Segments propagated together by :func:`rk4_stm`: the working set of a block stays in the
processor's cache (the result does not depend on it: every segment is independent)."""


def rk4_stm(s, thrust_n, dt, params: ParamDict, names: Sequence[str] = ("mass", "izz"),
            n_sub: int = 1):
    """Propagate states and transition matrices over hold segments of length ``dt``.

    Args:
        s: (..., 6) states at segment start.
        thrust_n: (..., 4) constant thrusts over the segment, N.
        dt: scalar or (...) segment lengths, s (0 allowed: gives the identity).
        params: keyword parameters of ``model.dynamics`` (mass, izz, arm, ct, cr, kb,
            ax, ay, cx, cy), each a scalar or an array broadcastable to the leading shape.
        names: the estimated parameters, the extra columns of Phi.
        n_sub: RK4 steps per segment.

    Returns:
        ``(s_end (..., 6), Phi (..., 6+p, 6+p))``.

    Each RK4 stage evaluates the rates and the Jacobian once, with only the effects that
    are present compiled in (:func:`_stage_function`); one leading dimension of scalar
    parameters is propagated in blocks of :data:`STM_BLOCK` segments.
    """
    names = tuple(names)
    s = np.asarray(s, dtype=float)
    n = 6 + len(names)
    lead = np.broadcast_shapes(s.shape[:-1], np.shape(thrust_n)[:-1], np.shape(dt))
    s = np.broadcast_to(s, lead + (6,))
    w = np.broadcast_to(wrench(thrust_n, params.get("arm", ARM_M)), lead + (3,))
    h = np.broadcast_to(np.asarray(dt, dtype=float) / n_sub, lead)
    pv = [params.get(k, 0.0) for k in PARAM_NAMES]
    stage = _stage_function(params, names)
    s_end = np.empty(lead + (6,))
    full = np.zeros(lead + (n, n))
    full[..., 6:, 6:] = np.eye(len(names))
    if len(lead) == 1 and all(np.ndim(v) == 0 for v in pv):
        for a in range(0, lead[0], STM_BLOCK):
            b = a + STM_BLOCK
            _rk4_stm_block(stage, s[a:b], w[a:b], h[a:b], pv, n_sub, s_end[a:b], full[a:b])
    else:
        _rk4_stm_block(stage, s, w, h, pv, n_sub, s_end, full)
    return s_end, full


def _rk4_stm_block(stage, s, w, h, pv, n_sub: int, s_end, full) -> None:
    """:func:`rk4_stm` of one block: end states into ``s_end``, the top six rows of the
    transition matrices into ``full[..., :6, :]``.

    The stage matrices ``dPhi = J_s Phi + [0 J_theta]`` are formed in preallocated buffers
    (the first stage from ``Phi = [I 0]`` without a product), in the same order of
    operations as RK4 written out on whole arrays.
    """
    f, cols_s, cols_t = stage
    lead = s.shape[:-1]
    n = full.shape[-1]
    s = s.copy()
    h = h[..., None]
    hm = h[..., None]
    fx, fy, mz = w[..., 0], w[..., 1], w[..., 2]
    Js = np.zeros(lead + (6, 6))  # zero outside the Jacobian's pattern
    Jt = np.zeros(lead + (6, n - 6))

    def rate(q, phi_top, out):
        """sdot (..., 6); d Phi_top / dt written into ``out`` (None: Phi_top = [I 0])."""
        rates, vals = f(q[..., 2], q[..., 3], q[..., 4], q[..., 5], fx, fy, mz, *pv)
        for k, i, j in cols_s:
            Js[..., i, j] = vals[k]
        for k, i, j in cols_t:
            Jt[..., i, j] = vals[k]
        if phi_top is None:
            out[..., :6] = Js
            out[..., 6:] = Jt
        else:
            np.matmul(Js, phi_top, out=out)
            out[..., 6:] += Jt
        sdot = np.empty(lead + (6,))
        for i, v in enumerate(rates):
            sdot[..., i] = v
        return sdot

    phi = np.zeros(lead + (6, n))
    phi[..., :, :6] = np.eye(6)
    k1p, k2p, k3p, k4p, tmp = (np.empty(lead + (6, n)) for _ in range(5))
    for sub in range(n_sub):
        k1s = rate(s, None if sub == 0 else phi, k1p)
        np.multiply(0.5 * hm, k1p, out=tmp)
        k2s = rate(s + 0.5 * h * k1s, np.add(phi, tmp, out=tmp), k2p)
        np.multiply(0.5 * hm, k2p, out=tmp)
        k3s = rate(s + 0.5 * h * k2s, np.add(phi, tmp, out=tmp), k3p)
        np.multiply(hm, k3p, out=tmp)
        k4s = rate(s + h * k3s, np.add(phi, tmp, out=tmp), k4p)
        s = s + h / 6.0 * (k1s + 2 * k2s + 2 * k3s + k4s)
        # phi + hm/6 (k1p + 2 k2p + 2 k3p + k4p)
        np.multiply(2, k2p, out=tmp)
        np.add(k1p, tmp, out=tmp)
        np.multiply(2, k3p, out=k2p)
        np.add(tmp, k2p, out=tmp)
        np.add(tmp, k4p, out=tmp)
        np.multiply(hm / 6.0, tmp, out=tmp)
        np.add(phi, tmp, out=phi)
    s_end[...] = s
    full[..., :6, :] = phi


# --------------------------------------------------------------------------------------
# The filters' propagation: RK4 of the state, the transition matrix assembled from the
# four stage Jacobians (the same RK4 as :func:`rk4_stm`, restructured for speed).


@dataclass(frozen=True, eq=False)
class AugmentedPlant:
    """The plant as a filter sees it: state ``z = (x, y, psi, u, v, r, theta)``.

    ``names`` are the estimated parameters (constant in the model), ``fixed`` the values
    of the others (keyword names of :func:`model.dynamics`; default arm 0.05 m, no
    friction, level). Only the effects of :data:`model.EFFECTS` that are present (a
    parameter non-zero or estimated) are compiled in.
    """

    names: tuple[str, ...]
    fixed: tuple[tuple[str, float], ...]

    @staticmethod
    def of(names: Sequence[str] = ("mass", "izz"), fixed: Mapping[str, float] | None = None
           ) -> AugmentedPlant:
        vals = {"arm": ARM_M, "ct": 0.0, "cr": 0.0, "kb": 0.0, "ax": 0.0, "ay": 0.0,
                "cx": 0.0, "cy": 0.0}
        vals.update({k: float(v) for k, v in (fixed or {}).items()})
        return _plant(tuple(names), tuple(sorted(vals.items())))

    def __post_init__(self):
        fixed = dict(self.fixed)
        n = 6 + len(self.names)
        eff = active_effects(fixed, self.names)
        pattern = jacobian_pattern(eff, self.names)
        set_ = object.__setattr__
        set_(self, "n", n)
        set_(self, "arm", fixed.get("arm", ARM_M))
        set_(self, "effects", eff)
        set_(self, "pattern", pattern)
        set_(self, "flat", np.array([i * n + j for i, j in pattern], dtype=np.intp))
        set_(self, "stage", scalar_stage(eff, self.names))
        set_(self, "array_stage", array_function(eff, self.names))
        # where each of PARAM_NAMES comes from: z[6 + j] or a constant
        src = [(6 + self.names.index(p), None) if p in self.names else (None, fixed.get(p, 0.0))
               for p in PARAM_NAMES]
        set_(self, "_src", src)

    def params(self, z) -> tuple:
        """(mass, izz, ct, cr, kb, ax, ay, cx, cy) at the augmented state ``z`` (floats or arrays)."""
        return tuple(z[i] if i is not None else c for i, c in self._src)


@lru_cache(maxsize=64)
def _plant(names, fixed) -> AugmentedPlant:
    return AugmentedPlant(names, fixed)


_NW = 10  # RK4-STM slabs per step: 4 stage Jacobians, 3 + 2 + 1 products (the 11th: identity)
_COEF_POW = np.array([1, 1, 1, 1, 2, 2, 2, 3, 3, 4, 0])
_COEF = np.array([1 / 6, 1 / 3, 1 / 3, 1 / 6, 1 / 6, 1 / 6, 1 / 6, 1 / 12, 1 / 12, 1 / 24, 1.0])
_TLS = threading.local()


def _workspace(plant: AugmentedPlant, k: int) -> np.ndarray:
    """Per-thread (k, 11, n, n) scratch for ``plant``: slabs 0-3 the stage Jacobians (zero
    outside the plant's pattern), 4-9 their products, 10 the identity."""
    cache = getattr(_TLS, "ws", None)
    if cache is None:
        cache = _TLS.ws = {}
    key = (id(plant), k)
    W = cache.get(key)
    if W is None:
        n = plant.n
        W = np.zeros((k, _NW + 1, n, n))
        W[:, _NW] = np.eye(n)
        cache[key] = W
    return W


def _put_index(plant: AugmentedPlant, k: int) -> np.ndarray:
    cache = getattr(_TLS, "put", None)
    if cache is None:
        cache = _TLS.put = {}
    idx = cache.get((id(plant), k))
    if idx is None:
        nn = plant.n * plant.n
        idx = np.concatenate([plant.flat + (i * (_NW + 1) + s) * nn
                              for i in range(k) for s in range(4)])
        cache[(id(plant), k)] = idx
    return idx


def stm_coefficients(h) -> np.ndarray:
    """(..., 11) weights of the workspace slabs in the RK4 transition matrix of a step h::

        Phi = I + h/6 (A1 + 2 A2 + 2 A3 + A4) + h^2/6 (A2A1 + A3A2 + A4A3)
                + h^3/12 (A3A2A1 + A4A3A2) + h^4/24 A4A3A2A1

    (RK4 on ``Phi' = A(t) Phi`` from ``Phi = I`` with stage matrices A1..A4, exactly).
    """
    return _COEF * np.asarray(h, dtype=float)[..., None] ** _COEF_POW


def rk4_step(zl: list, h: float, fx: float, fy: float, mz: float, p: tuple, stage, vals: list):
    """One RK4 step of the augmented state (list of floats) under a constant wrench; appends
    the four stage Jacobians' entries to ``vals``. ``p``: (mass, izz, ct, cr, kb, ax, ay, cx, cy)."""
    x, y, psi, u, v, r = zl[0], zl[1], zl[2], zl[3], zl[4], zl[5]
    m, izz, ct, cr, kb, ax, ay, cx, cy = p
    h2 = 0.5 * h
    k1 = stage(psi, u, v, r, fx, fy, mz, m, izz, ct, cr, kb, ax, ay, vals, cx, cy)
    k2 = stage(psi + h2 * k1[2], u + h2 * k1[3], v + h2 * k1[4], r + h2 * k1[5], fx, fy, mz,
               m, izz, ct, cr, kb, ax, ay, vals, cx, cy)
    k3 = stage(psi + h2 * k2[2], u + h2 * k2[3], v + h2 * k2[4], r + h2 * k2[5], fx, fy, mz,
               m, izz, ct, cr, kb, ax, ay, vals, cx, cy)
    k4 = stage(psi + h * k3[2], u + h * k3[3], v + h * k3[4], r + h * k3[5], fx, fy, mz,
               m, izz, ct, cr, kb, ax, ay, vals, cx, cy)
    h6 = h / 6.0
    out = [x + h6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0]),
           y + h6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1]),
           psi + h6 * (k1[2] + 2 * k2[2] + 2 * k3[2] + k4[2]),
           u + h6 * (k1[3] + 2 * k2[3] + 2 * k3[3] + k4[3]),
           v + h6 * (k1[4] + 2 * k2[4] + 2 * k3[4] + k4[4]),
           r + h6 * (k1[5] + 2 * k2[5] + 2 * k3[5] + k4[5])]
    if len(zl) > 6:
        out += zl[6:]
    return out


def _coef(h: float) -> list:
    """:func:`stm_coefficients` of one step, as a list (cheaper for a single step)."""
    h2 = h * h / 6.0
    h3 = h * h * h / 12.0
    return [h / 6.0, h / 3.0, h / 3.0, h / 6.0, h2, h2, h2, h3, h3, h * h * h * h / 24.0, 1.0]


def step_stms(plant: AugmentedPlant, vals: list, hs: list) -> np.ndarray:
    """(k, n, n) transition matrices of k consecutive RK4 steps from their stage entries."""
    k = len(hs)
    n = plant.n
    W = _workspace(plant, k)
    W.put(_put_index(plant, k), vals)
    if k == 1:  # one step (most pose intervals): plain 2-d products are cheaper
        w = W[0]
        np.matmul(w[1:4], w[0:3], out=w[4:7])
        np.matmul(w[2:4], w[4:6], out=w[7:9])
        np.dot(w[3], w[7], out=w[9])
        return np.dot(np.array(_coef(hs[0])), w.reshape(_NW + 1, n * n)).reshape(1, n, n)
    np.matmul(W[:, 1:4], W[:, 0:3], out=W[:, 4:7])
    np.matmul(W[:, 2:4], W[:, 4:6], out=W[:, 7:9])
    np.matmul(W[:, 3], W[:, 7], out=W[:, 9])
    c = np.array([_coef(h) for h in hs])
    return np.matmul(c[:, None, :], W.reshape(k, _NW + 1, n * n)).reshape(k, n, n)


def propagate_stm(z, seg_dt, seg_w, plant: AugmentedPlant, max_step_s: float = 0.01,
                  per_step: bool = False):
    """Propagate one augmented state and its transition matrix over hold segments.

    Args:
        z: (n,) state at the start.
        seg_dt: segment lengths, s (zero-length segments are skipped).
        seg_w: matching body wrenches (Fx N, Fy N, Mz N m).
        plant: the model (:class:`AugmentedPlant`).
        max_step_s: longest RK4 step; longer segments are split evenly.
        per_step: return every step's transition matrix and length instead of the product.

    Returns:
        ``(z_end (n,), Phi (n, n))``, or with ``per_step`` ``(z_end, Phis (k, n, n), hs)``.
    """
    zl = z.tolist() if isinstance(z, np.ndarray) else [float(a) for a in z]
    p = plant.params(zl)
    stage = plant.stage
    vals: list[float] = []
    hs: list[float] = []
    for dt, w in zip(seg_dt, seg_w, strict=True):
        if dt <= 0.0:
            continue
        fx, fy, mz = w
        if dt <= max_step_s:
            zl = rk4_step(zl, dt, fx, fy, mz, p, stage, vals)
            hs.append(dt)
            continue
        k = max(1, math.ceil(dt / max_step_s - 1e-9))
        h = dt / k
        for _ in range(k):
            zl = rk4_step(zl, h, fx, fy, mz, p, stage, vals)
            hs.append(h)
    if per_step:
        return np.array(zl), (step_stms(plant, vals, hs) if hs else np.empty((0, plant.n, plant.n))), hs
    if not hs:
        return np.array(zl), np.eye(plant.n)
    phis = step_stms(plant, vals, hs)
    phi = phis[0]
    for i in range(1, len(hs)):
        phi = np.dot(phis[i], phi)
    return np.array(zl), phi


def _batch_stage(plant: AugmentedPlant, s, w, p, J):
    """Rates (R, 6) of many states under one wrench; the Jacobian entries written into J (R, n*n)."""
    rates, vals = plant.array_stage(s[:, 2], s[:, 3], s[:, 4], s[:, 5], w[0], w[1], w[2], *p)
    for q, v in zip(plant.flat.tolist(), vals, strict=True):
        J[:, q] = v
    out = np.empty_like(s)
    for i, v in enumerate(rates):
        out[:, i] = v
    return out


def propagate_stm_batch(x, seg_dt, seg_w, plant: AugmentedPlant, max_step_s: float = 0.01):
    """:func:`propagate_stm` for R states at once (shared segments and wrenches).

    Returns ``(x_end (R, n), Phi (R, n, n))``.
    """
    x = np.asarray(x, dtype=float)
    R, n = x.shape
    s = x[:, :6]
    p = plant.params(x.T)
    phi = None
    W = None
    for dt, w in zip(seg_dt, seg_w, strict=True):
        if dt <= 0.0:
            continue
        k = max(1, math.ceil(dt / max_step_s - 1e-9))
        h = dt / k
        for _ in range(k):
            if W is None:
                W = np.zeros((_NW, R, n * n))
            k1 = _batch_stage(plant, s, w, p, W[0])
            k2 = _batch_stage(plant, s + 0.5 * h * k1, w, p, W[1])
            k3 = _batch_stage(plant, s + 0.5 * h * k2, w, p, W[2])
            k4 = _batch_stage(plant, s + h * k3, w, p, W[3])
            s = s + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
            A = W.reshape(_NW, R, n, n)
            np.matmul(A[1:4], A[0:3], out=A[4:7])
            np.matmul(A[2:4], A[4:6], out=A[7:9])
            np.matmul(A[3], A[7], out=A[9])
            ph = (stm_coefficients(h)[:_NW] @ W.reshape(_NW, R * n * n)).reshape(R, n * n)
            ph[:, ::n + 1] += 1.0
            ph = ph.reshape(R, n, n)
            phi = ph if phi is None else ph @ phi
    out = x.copy()
    out[:, :6] = s
    if phi is None:
        phi = np.broadcast_to(np.eye(n), (R, n, n)).copy()
    return out, phi


def rk4_states(s, w, h: float, n: int, params: Mapping[str, Any]):
    """``n`` RK4 steps of length ``h`` of states (..., 6) under one wrench ``w`` (3,), state
    only (the Monte Carlo truth); ``params`` as :func:`model.dynamics` (arrays allowed)."""
    p = tuple(params.get(k, 0.0) for k in PARAM_NAMES)
    f = array_function(active_effects(params), None)
    fx, fy, mz = w

    def rate(q):
        out = np.empty_like(q)
        for i, v in enumerate(f(q[..., 2], q[..., 3], q[..., 4], q[..., 5], fx, fy, mz, *p)):
            out[..., i] = v
        return out

    for _ in range(n):
        k1 = rate(s)
        k2 = rate(s + 0.5 * h * k1)
        k3 = rate(s + 0.5 * h * k2)
        k4 = rate(s + h * k3)
        s = s + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    return s
