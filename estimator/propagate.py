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

from collections.abc import Mapping, Sequence

import numpy as np

from estimator.model import dynamics, jac_params, jac_state

ParamDict = Mapping[str, "float | np.ndarray"]


def _top_rate(s, thrust, params: ParamDict, names: Sequence[str], phi_top):
    """RHS of the state and of the top 6 rows of Phi: (sdot (...,6), phidot (...,6,n))."""
    Js = jac_state(s, thrust, **params)
    Jt = jac_params(s, thrust, **params, names=tuple(names))
    dphi = Js @ phi_top
    dphi[..., 6:] += Jt
    return dynamics(s, thrust, **params), dphi


def rk4_stm(s, thrust_n, dt, params: ParamDict, names: Sequence[str] = ("mass", "izz"),
            n_sub: int = 1):
    """Propagate states and transition matrices over hold segments of length ``dt``.

    Args:
        s: (..., 6) states at segment start.
        thrust_n: (..., 4) constant thrusts over the segment, N.
        dt: scalar or (...) segment lengths, s (0 allowed: gives the identity).
        params: keyword parameters of ``model.dynamics`` (mass, izz, arm, ct, cr, kb,
            ax, ay), each a scalar or an array broadcastable to the leading shape.
        names: the estimated parameters, the extra columns of Phi.
        n_sub: RK4 steps per segment.

    Returns:
        ``(s_end (..., 6), Phi (..., 6+p, 6+p))``.
    """
    s = np.asarray(s, dtype=float)
    p = len(names)
    n = 6 + p
    lead = np.broadcast_shapes(s.shape[:-1], np.shape(thrust_n)[:-1], np.shape(dt))
    s = np.broadcast_to(s, lead + (6,)).copy()
    h = (np.asarray(dt, dtype=float) / n_sub)[..., None]
    hm = h[..., None]
    phi = np.zeros(lead + (6, n))
    phi[..., :, :6] = np.eye(6)
    for _ in range(n_sub):
        k1s, k1p = _top_rate(s, thrust_n, params, names, phi)
        k2s, k2p = _top_rate(s + 0.5 * h * k1s, thrust_n, params, names, phi + 0.5 * hm * k1p)
        k3s, k3p = _top_rate(s + 0.5 * h * k2s, thrust_n, params, names, phi + 0.5 * hm * k2p)
        k4s, k4p = _top_rate(s + h * k3s, thrust_n, params, names, phi + hm * k3p)
        s = s + h / 6.0 * (k1s + 2 * k2s + 2 * k3s + k4s)
        phi = phi + hm / 6.0 * (k1p + 2 * k2p + 2 * k3p + k4p)
    full = np.zeros(lead + (n, n))
    full[..., :6, :] = phi
    full[..., 6:, 6:] = np.eye(p)
    return s, full


def zoh_segments(cmd_t: np.ndarray, t_nodes: np.ndarray):
    """Split ``[t_nodes[0], t_nodes[-1]]`` at every node and every command switch.

    Args:
        cmd_t: (Nc,) increasing switch times; row j holds on [cmd_t[j], cmd_t[j+1]).
        t_nodes: (N,) non-decreasing times that must be segment boundaries (poses).

    Returns:
        ``(events, cmd_idx, node_pos)``: (M,) boundary times, (M-1,) index of the
        command row active on each segment (-1 before the first command: zero
        thrust), and (N,) position of each node in ``events``.
    """
    cmd_t = np.asarray(cmd_t, dtype=float)
    t_nodes = np.asarray(t_nodes, dtype=float)
    inner = cmd_t[(cmd_t > t_nodes[0]) & (cmd_t < t_nodes[-1])]
    events = np.union1d(t_nodes, inner)
    cmd_idx = np.searchsorted(cmd_t, events[:-1], side="right") - 1
    node_pos = np.searchsorted(events, t_nodes)
    return events, cmd_idx, node_pos


def segment_thrust(thrust_n: np.ndarray, cmd_idx: np.ndarray) -> np.ndarray:
    """(M-1, 4) thrust on each segment (zero before the first command)."""
    thrust_n = np.asarray(thrust_n, dtype=float)
    out = thrust_n[np.clip(cmd_idx, 0, None)]
    out[cmd_idx < 0] = 0.0
    return out
