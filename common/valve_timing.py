"""Known valve timing of a vehicle (vehicle.toml ``[valves]``) applied to a
zero-order-hold input: a dead time (:func:`delayed`) and a first-order rise
(:func:`first_order_rise`). Both return a new zero-order hold ``(t, values)`` that the
plant's segments integrate as usual (the hold segments split at every switch time inside
a pose interval, so the switching instants are exact, not rounded to pose times).

First-order rise, ``tau f' = u - f``: after each switch the force is
``u + (f0 - u) exp(-(t - ts)/tau)``. Each hold segment is cut into sub-segments of
``tau / 4`` up to ``8 tau`` after the switch (then one to the next switch) and every
sub-segment holds the EXACT mean of the exponential over it: the impulse of every
sub-segment, hence the velocity at its end, is exact. Only the position within a
sub-segment of length h moves, by at most ``|df| h^2 / (4 m)`` for a force change ``df``
across it; summed over a switch of size ``du``: ``|du| tau^2 / (64 m)`` for the short
sub-segments plus ``|du| exp(-8) L^2 / (4 m)`` for the last one of length L (the same with
Izz for the yaw). For tau = 20 ms, du = 0.45 N, m = 23 kg, L = 1 s: 0.12 um + 1.7 um.
"""

from __future__ import annotations

import numpy as np

SUB_STEP_TAU = 0.25
"""Sub-segment length after a switch, in time constants."""
CUTOFF_TAU = 8.0
"""Sub-segments are cut up to this many time constants after a switch (exp(-8) = 3.4e-4)."""


def delayed(t: np.ndarray, values: np.ndarray, delay_s: float) -> tuple[np.ndarray, np.ndarray]:
    """A hold ``(t (N,), values (N, C))`` seen through a dead time: every switch ``delay_s``
    later, zeros (closed valves) from ``t[0]`` until the first command arrives."""
    t = np.asarray(t, dtype=float)
    values = np.asarray(values, dtype=float)
    if delay_s <= 0:
        return t, values
    return (np.concatenate([[t[0]], t + delay_s]),
            np.vstack([np.zeros((1,) + values.shape[1:]), values]))


def first_order_rise(t: np.ndarray, values: np.ndarray, rise_s: float,
                     start: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """A hold ``(t (N,), values (N, C))`` through a first-order lag of time constant
    ``rise_s`` (see the module doc for the sub-segments and their error), starting from
    ``start`` (C,) (default zeros: valves closed). The last row (the end) keeps its time."""
    t = np.asarray(t, dtype=float)
    u = np.asarray(values, dtype=float)
    if rise_s <= 0:
        return t, u
    f = np.zeros(u.shape[1]) if start is None else np.asarray(start, dtype=float).copy()
    out_t: list[float] = []
    out_v: list[np.ndarray] = []
    edges = np.arange(1, int(CUTOFF_TAU / SUB_STEP_TAU) + 1) * SUB_STEP_TAU * rise_s
    for i in range(len(t) - 1):
        t0, t1, ui = t[i], t[i + 1], u[i]
        gap = f - ui
        if not np.any(gap):
            out_t.append(t0)
            out_v.append(ui.copy())
            continue
        cuts = np.concatenate([[0.0], edges[edges < t1 - t0], [t1 - t0]])
        e = np.exp(-cuts / rise_s)
        mean = ui[None, :] + gap[None, :] * (rise_s * (e[:-1] - e[1:]) / np.diff(cuts))[:, None]
        out_t.extend(t0 + cuts[:-1])
        out_v.extend(mean)
        f = ui + gap * e[-1]
    out_t.append(t[-1])
    out_v.append(u[-1].copy())
    return np.asarray(out_t), np.vstack(out_v)
