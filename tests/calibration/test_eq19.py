"""Equation 19, its inverse and its uncertainty budget (checked by Monte Carlo)."""

import math

import numpy as np
import pytest

from calibration.swing.bifilar import (
    eq19_budget,
    izz_eq19,
    izz_from_times,
    period_eq19,
    period_from_times,
)
from common.errors import UserError


def test_eq19_hand_values():
    # 0.72 * 9.80665 * 0.1^2 * 1.64^2 / (16 pi^2 * 1.0):
    # 7.060788 * 0.01 * 2.6896 = 0.189904954...; 16 pi^2 = 157.913670...; ratio 1.2026e-3
    assert izz_eq19(0.72, 0.1, 1.0, 1.64) == pytest.approx(1.2025998e-3, rel=1e-7)
    # 2.268 * 9.80665 * 0.0064 * 4 / (157.91367 * 0.6) = 0.5693686 / 94.748202 = 6.00942e-3
    assert izz_eq19(2.268, 0.08, 0.6, 2.0) == pytest.approx(6.009422e-3, rel=1e-6)
    # g enters linearly
    assert izz_eq19(1.0, 0.2, 1.0, 1.0, g=9.81) / izz_eq19(1.0, 0.2, 1.0, 1.0, g=9.80665) == \
        pytest.approx(9.81 / 9.80665)
    # broadcasting and the inverse
    T = np.array([1.0, 1.5, 2.0])
    np.testing.assert_allclose(period_eq19(izz_eq19(0.72, 0.1, 1.0, T), 0.72, 0.1, 1.0), T)


def test_period_from_times_mean_and_type_a():
    times = [16.4, 16.5, 16.3, 16.45, 16.38]
    T, uT, sT = period_from_times(times, 10)
    assert T == pytest.approx(np.mean(times) / 10)
    assert sT == pytest.approx(np.std(np.array(times) / 10, ddof=1))
    assert uT == pytest.approx(sT / math.sqrt(5))


def test_budget_contributions_and_spacing_dominates():
    res = izz_from_times([16.4, 16.5, 16.3, 16.45, 16.38], 10, 0.72, 0.10, 1.0,
                         u_mass_kg=2.5e-3 / math.sqrt(3), u_spacing_m=1e-3, u_length_m=2e-3)
    c = res.contributions_kgm2
    I = res.izz_kgm2
    assert c["spacing"] == pytest.approx(I * 2 * 1e-3 / 0.10)
    assert c["length"] == pytest.approx(I * 2e-3 / 1.0)
    assert c["mass"] == pytest.approx(I * 2.5e-3 / math.sqrt(3) / 0.72)
    assert c["period"] == pytest.approx(I * 2 * res.details["u_period_s"] / res.details["period_s"])
    assert max(c, key=c.get) == "spacing"
    assert res.izz_sigma_kgm2 == pytest.approx(math.sqrt(sum(v * v for v in c.values())))


@pytest.mark.parametrize("case", [
    dict(m=0.72, D=0.10, h=1.0, T=1.64, um=1.4e-3, uD=1e-3, uh=2e-3, uT=3e-3),
    dict(m=2.268, D=0.08, h=0.6, T=2.0, um=5e-3, uD=2e-3, uh=5e-3, uT=1e-2),
    dict(m=3.0, D=0.30, h=1.5, T=3.1, um=2e-2, uD=5e-4, uh=1e-2, uT=2e-2),
])
def test_propagation_matches_monte_carlo(case):
    rng = np.random.default_rng(11)
    n = 200_000
    izz, sigma, _ = eq19_budget(case["m"], case["D"], case["h"], case["T"], u_mass_kg=case["um"],
                                u_spacing_m=case["uD"], u_length_m=case["uh"], u_period_s=case["uT"])
    draws = izz_eq19(rng.normal(case["m"], case["um"], n), rng.normal(case["D"], case["uD"], n),
                     rng.normal(case["h"], case["uh"], n), rng.normal(case["T"], case["uT"], n))
    # first-order propagation vs the spread of the inputs pushed through Eq. 19
    assert sigma == pytest.approx(draws.std(), rel=0.03)
    assert izz == pytest.approx(np.median(draws), rel=3 * sigma / izz / math.sqrt(n) + 2e-3)


def test_tare_subtracted_and_budgeted():
    a = izz_from_times([16.4, 16.5], 10, 0.72, 0.1, 1.0)
    b = izz_from_times([16.4, 16.5], 10, 0.72, 0.1, 1.0, tare_izz_kgm2=2e-4, u_tare_kgm2=1e-5)
    assert b.izz_kgm2 == pytest.approx(a.izz_kgm2 - 2e-4)
    assert b.izz_sigma_kgm2 == pytest.approx(math.hypot(a.izz_sigma_kgm2, 1e-5))
    with pytest.raises(UserError, match="tare"):
        izz_from_times([16.4, 16.5], 10, 0.72, 0.1, 1.0, tare_izz_kgm2=1.0)


@pytest.mark.parametrize("times,cycles,m,D,h,msg", [
    ([16.4], 10, 0.72, 0.1, 1.0, "at least 2 timings"),
    ([16.4, -16.5], 10, 0.72, 0.1, 1.0, "positive"),
    ([16.4, 16.5], 0, 0.72, 0.1, 1.0, "cycles"),
    ([16.4, 16.5], 10, 0.72, -0.1, 1.0, "spacing"),
    ([16.4, 16.5], 10, 0.72, 0.1, 0.0, "length"),
    ([16.4, 16.5], 10, -1.0, 0.1, 1.0, "mass"),
])
def test_bad_input_refused(times, cycles, m, D, h, msg):
    with pytest.raises(UserError, match=msg):
        izz_from_times(times, cycles, m, D, h)


# issue 16: --spacing 10 (cm typed as m) gave 12 kg m^2 for a 0.72 kg module without a word

def _times(izz=1.2e-3, m=0.72, D=0.10, h=1.0, cycles=10):
    T = float(period_eq19(izz, m, D, h))
    return [cycles * T * f for f in (0.999, 1.0, 1.001)], cycles


def test_plausible_geometry_gives_no_warning():
    times, cycles = _times()
    assert izz_from_times(times, cycles, 0.72, 0.10, 1.0).warnings == []


def test_spacing_typed_in_cm_warns_in_one_line():
    times, cycles = _times()
    res = izz_from_times(times, cycles, 0.72, 10.0, 1.0)
    assert res.izz_kgm2 == pytest.approx(12.0, rel=0.01)
    assert len(res.warnings) == 1 and "\n" not in res.warnings[0]
    assert "string spacing D = 10 m" in res.warnings[0] and "cm or mm" in res.warnings[0]
    assert res.to_dict()["warnings"] == res.warnings


def test_length_in_cm_and_period_off_the_geometry_warn():
    times, cycles = _times()
    res = izz_from_times(times, cycles, 0.72, 0.10, 100.0)
    assert any("string length h = 100 m" in w for w in res.warnings)
    assert any("does not fit the geometry" in w for w in res.warnings)
