"""A vehicle's known valve timing in the live filter: the hold segments of one
pose interval through the valves' dead time and first-order rise.

The live filter integrates a pose interval ``[t0, t1]`` over hold segments (durations and
body wrenches). Without valve timing they are the commands' own
(:meth:`estimator.live.core.LiveEstimator._segments`); a vehicle whose ``[valves]`` give a
``delay_s`` or ``rise_s`` acts on each command later and gradually.
:func:`timed_segments` takes the commands from the one in force ``delay_s + 8 rise_s``
before ``t0`` (its rise settled to ``exp(-8)``, valves closed before the first command),
passes them through :meth:`common.vehicle.Vehicle.input_profile`'s timing
(:func:`common.valve_timing.delayed`, :func:`common.valve_timing.first_order_rise`) and
cuts the result to ``[t0, t1]``: the same input as ``tpods estimate batch`` integrates on
the recorded run.
"""

from __future__ import annotations

import bisect
from collections.abc import Sequence

import numpy as np

from common.valve_timing import CUTOFF_TAU, first_order_rise
from estimator.plant.model import wrench


def has_timing(layout) -> bool:
    """True for a vehicle whose valves have a dead time or a rise."""
    valves = getattr(layout, "valves", None)
    return valves is not None and (valves.delay_s > 0 or valves.rise_s > 0)


def timed_hold(layout, cmd_t: Sequence[float], cmd_d: Sequence[Sequence[float]],
               t0: float, t1: float) -> tuple[np.ndarray, np.ndarray]:
    """The plant's input over ``[t0, t1]`` (``t1 > t0``) of the commands ``cmd_t`` (sorted
    lab times, s) with duties ``cmd_d`` (%): a hold ``(t (K,), virtual thrusts (K, 4) N)``
    with ``t[0] = t0`` and the last row at ``t1`` ending it, through the valve timing of
    ``layout`` (a :class:`common.vehicle.Vehicle`). Each row holds the exact mean of the
    rise over its span: the interval's own ends are cut points of the rise (a row at ``t0``
    and at ``t1`` repeating the command in force), so the impulse over ``[t0, t1]`` is
    exact but for the rise's ``exp(-8)`` settling before the look-back."""
    delay, rise = layout.valves.delay_s, layout.valves.rise_s
    lookback = delay + CUTOFF_TAU * rise
    i0 = bisect.bisect_right(cmd_t, t0 - lookback) - 1
    i1 = bisect.bisect_right(cmd_t, t1 - delay)
    settled = i0 >= 0  # a command in force `lookback` before t0: its force has settled
    i0 = max(i0, 0)
    if i1 <= i0:  # nothing acts before t1: valves closed
        return np.array([t0, t1]), np.zeros((2, 4))
    v = layout.virtual_thrust(np.asarray(cmd_d[i0:i1], dtype=float), clamp=True)
    t = np.asarray(cmd_t[i0:i1], dtype=float) + delay
    if not settled:  # closed before the first command acts
        t = np.concatenate([[min(t0, t[0]) - 1.0], t])
        v = np.vstack([np.zeros((1, v.shape[1])), v])
    for cut in (t0, t1):  # the interval's ends as rows: the rise's means split there
        k = int(np.searchsorted(t, cut, "right"))
        if t[k - 1] != cut:
            t = np.insert(t, k, cut)
            v = np.insert(v, k, v[k - 1], axis=0)
    t, v = first_order_rise(t, v, rise, start=v[0].copy())
    k0, k1 = int(np.searchsorted(t, t0, "left")), int(np.searchsorted(t, t1, "left"))
    return t[k0:k1 + 1], v[k0:k1 + 1]


def timed_segments(layout, cmd_t: Sequence[float], cmd_d: Sequence[Sequence[float]],
                   t0: float, t1: float, arm_m: float
                   ) -> tuple[list[float], list[tuple[float, float, float]]]:
    """Hold segments ``(durations s, body wrenches (fx N, fy N, mz N m))`` covering
    ``[t0, t1]`` (:func:`timed_hold`), as the live filter integrates them."""
    t, v = timed_hold(layout, cmd_t, cmd_d, t0, t1)
    w = wrench(v[:-1], arm_m)
    return np.diff(t).tolist(), [tuple(r) for r in w.tolist()]
