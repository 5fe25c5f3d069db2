"""Trace fit on simulated nonlinear swings: accuracy, the small-angle bias, refusals."""

import math

import numpy as np
import pytest

from calibration.swing.bifilar import Pendulum, fit_swing_trace, simulate_trace, swing_and_estimate
from common.errors import UserError

# (mass kg, Izz kg m^2, D m, h m, c1 1/s, c2 1/rad): a lone module (D/h 0.1), the nominal
# module on short strings (D/h 0.133), a truss on a wide suspension (D/h 0.2)
CASES = [
    (0.72, 1.2e-3, 0.10, 1.00, 0.004, 0.010),
    (2.268, 3.78e-3, 0.08, 0.60, 0.003, 0.020),
    (3.0, 0.05, 0.30, 1.50, 0.002, 0.010),
]


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("seed", [1, 2])
def test_fit_recovers_izz_where_small_angle_formula_fails(case, seed):
    m, I, D, h, c1, c2 = case
    p = Pendulum(m, I, D, h, c1=c1, c2=c2)
    t, psi = simulate_trace(p, release_deg=20, duration_s=30, noise_deg=1.0, drop=0.03,
                            yaw_offset_rad=[0.3, 3.1][seed - 1], seed=seed)
    fit = fit_swing_trace(t, psi, m, D, h, u_spacing_m=1e-3)
    err = fit.izz_kgm2 / I - 1
    small = fit.details["izz_small_angle_kgm2"] / I - 1
    assert abs(err) < 0.003, err
    assert small > 0.01, small  # the swing lengthens the period: Eq. 19 reads too high
    assert fit.details["amplitude_correction"] == pytest.approx((1 + err) / (1 + small) - 1)
    # the fit's own uncertainty is honest (within 5 sigma) and D dominates the budget
    assert abs(fit.izz_kgm2 - I) < 5 * fit.contributions_kgm2["fit"]
    c = fit.contributions_kgm2
    assert max(c, key=c.get) == "spacing"
    assert fit.details["amplitude_start_deg"] == pytest.approx(20, abs=2.5)
    assert fit.details["residual_rms_deg"] == pytest.approx(1.0, rel=0.1)


def test_fit_sensitivities_follow_eq19_exponents():
    p = Pendulum(0.72, 1.2e-3, 0.2, 0.5, c1=0.004, c2=0.01)  # D/h 0.4: rise and q matter
    t, psi = simulate_trace(p, noise_deg=0.2, duration_s=12, seed=4)
    fit = fit_swing_trace(t, psi, 0.72, 0.2, 0.5)
    s = fit.details["sensitivities_dlnizz"]
    assert s["mass"] == pytest.approx(1 / 0.72)
    # D and h enter mostly through m g D^2 / h, a little through D/h and the rise term
    assert s["spacing"] * 0.2 == pytest.approx(2.0, abs=0.05)
    assert s["length"] * 0.5 == pytest.approx(-1.0, abs=0.05)
    # check one against brute force: refit with a changed D
    fit2 = fit_swing_trace(t, psi, 0.72, 0.2 * 1.001, 0.5)
    assert math.log(fit2.izz_kgm2 / fit.izz_kgm2) / (0.2 * 0.001) == pytest.approx(s["spacing"],
                                                                                    rel=2e-3)


def test_rise_term_matters_at_wide_suspension():
    """Fitting without the body's rise KE biases Izz when D/h is large (documented size)."""
    p = Pendulum(0.72, 1.2e-3, 0.3, 0.6, c1=0.004)  # D/h = 0.5
    t, psi = simulate_trace(p, noise_deg=0.1, duration_s=10, seed=5)
    with_rise = fit_swing_trace(t, psi, 0.72, 0.3, 0.6)
    without = fit_swing_trace(t, psi, 0.72, 0.3, 0.6, vertical_ke=False)
    assert abs(with_rise.izz_kgm2 / 1.2e-3 - 1) < 5e-4
    assert without.izz_kgm2 / 1.2e-3 - 1 > 0.02  # +4.9 % here: mu = m D^4/(16 h^2 Izz) = 0.84


def test_demo_helper():
    d = swing_and_estimate(0.72, 1.2e-3, seed=3)
    assert abs(d.izz_error_rel) < 0.003 and d.small_angle_error_rel > 0.01
    assert d.fit.izz_kgm2 == pytest.approx(1.2e-3 * (1 + d.izz_error_rel))


def test_refuses_traces_that_do_not_oscillate():
    rng = np.random.default_rng(0)
    t = np.arange(0, 30, 1 / 120)
    with pytest.raises(UserError, match="does not oscillate"):  # noise only
        fit_swing_trace(t, rng.normal(0, 0.017, t.size), 0.72, 0.1, 1.0)
    with pytest.raises(UserError, match="does not oscillate"):  # a slow drift
        fit_swing_trace(t, 0.01 * t + rng.normal(0, 0.017, t.size), 0.72, 0.1, 1.0)
    p = Pendulum(0.72, 1.2e-3, 0.1, 1.0)
    t2, psi2 = simulate_trace(p, duration_s=2.2 * p.period0_s, seed=1)  # two swings only
    with pytest.raises(UserError, match="does not oscillate"):
        fit_swing_trace(t2, psi2, 0.72, 0.1, 1.0)
    with pytest.raises(UserError, match="samples"):
        fit_swing_trace(t[:5], t[:5], 0.72, 0.1, 1.0)
    with pytest.raises(UserError, match="spacing"):
        t3, psi3 = simulate_trace(p, seed=1)
        fit_swing_trace(t3, psi3, 0.72, -0.1, 1.0)


def test_yaw_in_degrees_warns():
    """issue 16: a trace in degrees gave a plausible-looking Izz without a word."""
    p = Pendulum(0.72, 1.2e-3, 0.10, 1.0, c1=0.004, c2=0.01)
    t, psi = simulate_trace(p, seed=1, wrap=False)
    assert fit_swing_trace(t, psi, 0.72, 0.10, 1.0).warnings == []
    res = fit_swing_trace(t, np.degrees(psi), 0.72, 0.10, 1.0)
    assert any("yaw in degrees instead of radians?" in w for w in res.warnings)
