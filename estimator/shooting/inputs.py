"""The thrusts a vehicle's commands give, per thruster, averaged over each integration step.

The thrust of thruster i is modelled as

    T_i(t) = e_i * (A_i(t - d) - drop * B_i(t - d))

with ``A_i`` the thrust the vehicle file states for the commanded duty (N; its tables, its
forces, its own known supply drop), ``B_i = A_i (k - 1)`` for an on/off valve with ``k``
valves of its supply open (the extra supply drop ``drop`` estimated beside the file's),
``e_i`` the thruster's efficiency (1 as stated) and ``d`` the valves' dead time. (A valve
stuck open is found from a constant wrench, :mod:`estimator.shooting.health`: eight separate
leaks are not identifiable.)

Each channel is a hold of the command rows; its average over a step ``[ta, tb]`` is the
difference of its running integral, which is piecewise linear in time. So the step
averages are exact for any dead time, and continuous (piecewise linear) in it: a dead
time is a smooth parameter of the fit, not a rounding to the integration grid.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from common.vehicle import Vehicle


@dataclass(frozen=True)
class ThrustChannels:
    """Command holds of the two channels (module doc).

    Attributes:
        t: (Nc + 1,) hold start times, s, and one last time after which the last row holds.
        a, b: (Nc, N) channel values on each hold, N.
        wrench: (3, N) body-frame Fx, Fy (N) and Mz about the tracked origin (N m) per
            newton of each thruster.
        names: thruster names.
        force_n: (N,) the stated nominal force of each thruster (its largest thrust in the
            run for a table valve), N.
        force_sigma_n: (N,) its stated 1-sigma (0 where the file states none), N.
    """

    t: np.ndarray
    a: np.ndarray
    b: np.ndarray
    wrench: np.ndarray
    names: tuple[str, ...]
    force_n: np.ndarray
    force_sigma_n: np.ndarray
    opens: np.ndarray  # (N,) rows in which each valve is commanded open
    tables: tuple = ()  # the thrust tables the thrusts come from (their uncertainty unused)

    def cumulative(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(knots (K,), C (K, 2N), D (K, 2N), rate (K, 2N))``: the running integral C of
        ``[a | b]`` and its integral D at the hold times, and the value held from each
        knot on (0 before the first command; the last row after the end)."""
        rows = np.concatenate([self.a, self.b], axis=1)
        far = self.t[-1] + 1e6
        knots = np.concatenate([[self.t[0] - 1e6], self.t, [far]])
        rate = np.concatenate([np.zeros((1, rows.shape[1])), rows, rows[-1:], rows[-1:]])
        dt = np.diff(knots)[:, None]
        c = np.zeros((len(knots), rows.shape[1]))
        d = np.zeros_like(c)
        c[1:] = np.cumsum(rate[:-1] * dt, axis=0)
        d[1:] = np.cumsum(c[:-1] * dt + 0.5 * rate[:-1] * dt ** 2, axis=0)
        return knots, c, d, rate

    def step_average(self, ta: np.ndarray, tb: np.ndarray, delay: float,
                     cum: tuple | None = None) -> np.ndarray:
        """(..., 2, N) the channels' averages over steps ``[ta, tb]`` (``ta``, ``tb`` of any
        one shape) with every switch ``delay`` s later and spread over :data:`SWITCH_S`
        (centred, so its timing is unchanged); 0 where ``tb == ta``. Smooth (C1) in the
        dead time: a least-squares fit of it does not stall on kinks."""
        cum = cum if cum is not None else self.cumulative()
        shape = np.shape(ta)
        ta, tb = np.ravel(ta) - delay, np.ravel(tb) - delay
        fa = _smoothed_integral(ta, cum)
        fb = _smoothed_integral(tb, cum)
        h = (tb - ta)[:, None]
        with np.errstate(invalid="ignore", divide="ignore"):
            avg = np.where(h > 0, (fb - fa) / np.where(h > 0, h, 1.0), 0.0)
        n = self.a.shape[1]
        return avg.reshape(shape + (2, n))


SWITCH_S = 0.01
"""A valve switch is modelled as a linear ramp of this length, centred on the switch time
(a real solenoid valve opens in a few ms; the ramp makes the thrust smooth in the dead
time)."""


def _integral2(x: np.ndarray, cum) -> np.ndarray:
    """D(x) (n, M): the second running integral at ``x`` (exact: quadratic between knots)."""
    knots, c, d, rate = cum
    i = np.clip(np.searchsorted(knots, x, side="right") - 1, 0, len(knots) - 2)
    u = (x - knots[i])[:, None]
    return d[i] + c[i] * u + 0.5 * rate[i] * u * u


def _smoothed_integral(x: np.ndarray, cum) -> np.ndarray:
    """The running integral C box-averaged over :data:`SWITCH_S` about ``x`` (n, M)."""
    w = SWITCH_S
    return (_integral2(x + 0.5 * w, cum) - _integral2(x - 0.5 * w, cum)) / w


def vehicle_channels(vehicle: Vehicle, cmd_t: np.ndarray, duty_pct: np.ndarray,
                     clamp: bool = False) -> ThrustChannels:
    """The channels of a vehicle's command rows ``(cmd_t (Nc,), duty_pct (Nc, N))``; the
    last row holds to the end (a run's commands close with an all-zero end row)."""
    cmd_t = np.asarray(cmd_t, float)
    duty = np.asarray(duty_pct, float)
    a = vehicle.thrust_n(duty, clamp=clamp)
    n = a.shape[1]
    b = np.zeros_like(a)
    for supply, idx in vehicle.onoff_supplies().items():
        k = vehicle.open_counts(duty, supply)
        b[:, idx] = a[:, idx] * np.maximum(k - 1, 0)[:, None]
    nominal = np.array([t.force_n if t.force_n is not None else float(np.max(a[:, i], initial=0.0))
                        for i, t in enumerate(vehicle.thrusters)])
    sig = np.array([t.force_sigma_n or 0.0 for t in vehicle.thrusters])
    t = np.concatenate([cmd_t, [cmd_t[-1] + 1.0]]) if len(cmd_t) else np.array([0.0, 1.0])
    if not len(cmd_t):
        a = b = np.zeros((1, n))
    return ThrustChannels(t, a, b, vehicle.module_wrench_matrix(),
                          tuple(th.name for th in vehicle.thrusters), nominal, sig,
                          np.sum(duty > 0, axis=0), vehicle.tables())
