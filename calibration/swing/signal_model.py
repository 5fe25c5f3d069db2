"""What a swing sensor records: the pendulum's motion plus the sensor's nuisances.

A :class:`SignalModel` predicts a trace y(t) (t from its first sample) as

    y = n0 + n1 t + swing(t) + mode2(t)

- ``swing``: the large-angle model of :mod:`calibration.swing.bifilar_model`, as the angle
  theta (a yaw in rad) or its rate th' (a gyro, rad/s), parameters ln w0^2, c1, c2,
  theta(0), th'(0); or, ``linear``, a damped sine exp(-s t)(a cos wd t + b sin wd t)
  with parameters ln wd^2, s, a, b (any unit: the period is scale-free);
- ``n0 + n1 t``: the yaw's equilibrium or a gyro's bias, and a linear drift;
- ``mode2``: an optional second damped sinusoid (the body's pendulum sway on its
  strings at about sqrt(g/L), or another mode), parameters a2, b2, ln w2^2, s2;
- ``curved`` (a linear swing only): a sensor whose reading is a smooth function of the
  angle (a laser spot on a wall moves as tan 2 theta, a camera adds perspective): the
  damped sine u enters as u + k2 u^2 + k3 u^3, which adds its 2nd and 3rd harmonics.

Damping coefficients (c1, c2, s, s2) are bounded below by zero: :meth:`SignalModel.bounds`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from calibration.swing.bifilar_eq19 import G_STANDARD
from calibration.swing.bifilar_model import model_state

SWING_NAMES = {False: ("ln_w0sq", "c1_per_s", "c2_per_rad", "theta0", "rate0"),
               True: ("ln_wdsq", "s_per_s", "a", "b")}
NUISANCE_NAMES = ("n0", "n1")
MODE2_NAMES = ("a2", "b2", "ln_w2sq", "s2_per_s")
CURVE_NAMES = ("k2", "k3")
DAMPING_NAMES = ("c1_per_s", "c2_per_rad", "s_per_s", "s2_per_s")


def damped_sine(tt: np.ndarray, lnw2: float, s: float, a: float, b: float) -> np.ndarray:
    """exp(-s tt) (a cos w tt + b sin w tt) with w = exp(lnw2 / 2)."""
    w = math.exp(0.5 * lnw2)
    return np.exp(-s * tt) * (a * np.cos(w * tt) + b * np.sin(w * tt))


@dataclass(frozen=True)
class SignalModel:
    """The prediction of one trace: ``rate`` (a gyro) or an angle-like signal; ``linear``
    (damped sine) or the large-angle model on a suspension of spacing D, length h."""

    rate: bool
    linear: bool
    mode2: bool
    spacing_m: float = 0.1
    length_m: float = 1.0
    g: float = G_STANDARD
    vertical_ke: bool = True
    curved: bool = False
    mode2_omega_min: float = 0.0
    """Lower bound of the second mode's frequency (rad/s): it must oscillate in the trace."""

    @property
    def names(self) -> tuple[str, ...]:
        return (SWING_NAMES[self.linear] + NUISANCE_NAMES + (MODE2_NAMES if self.mode2 else ())
                + (CURVE_NAMES if self.curved else ()))

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower bound 0 on every damping coefficient and ``mode2_omega_min`` on the second
        mode's frequency; none elsewhere."""
        lo = np.array([0.0 if n in DAMPING_NAMES else -np.inf for n in self.names])
        if self.mode2 and self.mode2_omega_min > 0:
            lo[self.names.index("ln_w2sq")] = 2.0 * math.log(self.mode2_omega_min)
        return lo, np.full(len(lo), np.inf)

    def __call__(self, beta: np.ndarray, t: np.ndarray, spacing_m: float | None = None,
                 length_m: float | None = None, g: float | None = None) -> np.ndarray:
        """The predicted trace at times t (t[0] is time zero)."""
        tt = t - t[0]
        ns = len(SWING_NAMES[self.linear])
        if self.linear:
            y = damped_sine(tt, *beta[:4])
            if self.curved:
                k2, k3 = beta[-2:]
                y = y + k2 * y * y + k3 * y * y * y
        else:
            lw2, c1, c2, a0, v0 = (float(v) for v in beta[:5])  # plain floats: fast RK4
            th, om = model_state(t, a0, v0, math.exp(lw2), c1, c2,
                                 self.spacing_m if spacing_m is None else spacing_m,
                                 self.length_m if length_m is None else length_m,
                                 self.g if g is None else g, self.vertical_ke)
            y = om if self.rate else th
        y = y + beta[ns] + beta[ns + 1] * tt
        if self.mode2:
            a2, b2, lw2s, s2 = beta[ns + 2:ns + 6]
            y = y + damped_sine(tt, lw2s, s2, a2, b2)
        return y

    def swing_only(self, beta: np.ndarray, t: np.ndarray) -> np.ndarray:
        """The swing term alone (no offset, drift or second mode): what the plots show."""
        ns = len(SWING_NAMES[self.linear])
        b = np.array(beta, float)
        b[ns:ns + 2] = 0.0
        m = SignalModel(self.rate, self.linear, False, self.spacing_m, self.length_m, self.g,
                        self.vertical_ke, self.curved)
        return m(np.r_[b[:ns + 2], b[len(b) - 2:]] if self.curved else b[:ns + 2], t)


def angle_start_from_damped_sine(lnwd2: float, s: float, a: float, b: float, rate: bool
                                 ) -> tuple[float, float]:
    """theta(0), th'(0) of a damped sine fitted to the angle (``rate`` False) or to the
    rate (True: the angle is its integral, exp(-s t)(p cos + q sin))."""
    w = math.exp(0.5 * lnwd2)
    if not rate:
        return a, -s * a + w * b
    den = s * s + w * w
    p = (-s * a - w * b) / den
    return p, a
