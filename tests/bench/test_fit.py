import math

import numpy as np
import pandas as pd
import pytest

from bench.fit import (
    design_matrix,
    fit_orders,
    fit_polynomial,
    fit_steps,
    max_error_pct_full_scale,
    select_order,
)
from common.errors import UserError
from common.thrust_table import ThrustTable

D = np.arange(10.0, 91.0, 10.0)
TABLE = ThrustTable.default()


def test_recovers_table2_cubic_exactly_and_matches_normal_equations():
    z = TABLE.per_nozzle(D, 1)
    f = fit_polynomial(D, z, 3)
    np.testing.assert_allclose(f.coefficients, TABLE.coefficients[1], rtol=1e-8)
    assert f.rms < 1e-9
    # Eq. 11 literally, on a less extreme case (order 2)
    H = design_matrix(D, 2)
    x = np.linalg.solve(H.T @ H, H.T @ z)
    np.testing.assert_allclose(fit_polynomial(D, z, 2).coefficients, x, rtol=1e-7)


def test_covariance_and_loo_cv_against_brute_force():
    rng = np.random.default_rng(3)
    z = TABLE.per_nozzle(D, 2) + rng.normal(0, 0.3, D.size)
    f = fit_polynomial(D, z, 3)
    # covariance: numpy's polyfit (descending powers, unscaled covariance with the same s^2)
    _, cov = np.polyfit(D, z, 3, cov="unscaled")
    s2 = f.rss / (D.size - 4)
    np.testing.assert_allclose(f.covariance, (s2 * cov)[::-1, ::-1], rtol=1e-6)
    # leave-one-step-out: refit without each point
    errs = []
    for i in range(D.size):
        m = np.arange(D.size) != i
        g = fit_polynomial(D[m], z[m], 3)
        errs.append(z[i] - g.predict(D[i]))
    assert f.cv_rms == pytest.approx(math.sqrt(np.mean(np.square(errs))), rel=1e-8)


def test_order_selection_picks_the_true_order():
    rng = np.random.default_rng(0)
    picked = {"aicc": [], "bic": [], "cv": []}
    for _ in range(20):
        z = TABLE.per_nozzle(D, 1) + rng.normal(0, 0.1, D.size)
        fits = fit_orders(D, z)
        assert sorted(fits) == [1, 2, 3, 4]
        for c in picked:
            picked[c].append(select_order(fits, c))
    assert picked["aicc"].count(3) >= 17       # the paper's choice, 3, for a cubic truth
    assert all(n >= 3 for n in picked["aicc"])
    line = 2.0 + 0.3 * D + rng.normal(0, 0.1, D.size)
    assert select_order(fit_orders(D, line), "aicc") == 1


def test_fit_steps_table_and_statistics():
    rows = [{"n_open": k, "duty_pct": d, "thrust_gf": float(TABLE.per_nozzle(d, k)), "std_gf": 0.2}
            for k in (1, 2, 3, 4) for d in D]
    res = fit_steps(pd.DataFrame(rows), order="auto")
    t = res.table(60.0, source="test")
    assert t.unit == "gf" and t.duty_range == (10.0, 90.0) and t.pressure_psi == 60.0
    errs = max_error_pct_full_scale(t, TABLE)
    assert max(errs.values()) < 1e-6
    stats = t.extra["fit"]["nozzles"]["2"]
    assert stats["order"] in (3, 4) and len(stats["covariance"]) == stats["order"] + 1
    assert set(stats["orders"]) == {"1", "2", "3", "4"}
    fixed = fit_steps(pd.DataFrame(rows), order=2)
    assert set(fixed.selected.values()) == {2}


def test_table_roundtrips_through_toml(tmp_path):
    rows = [{"n_open": 1, "duty_pct": d, "thrust_gf": float(TABLE.per_nozzle(d, 1)) + 0.01 * (-1) ** i}
            for i, d in enumerate(D)]
    t = fit_steps(pd.DataFrame(rows)).table()
    t.save(tmp_path / "t.toml")
    back = ThrustTable.load(tmp_path / "t.toml")
    assert back.coefficients == t.coefficients
    assert back.extra["fit"]["nozzles"]["1"]["n_steps"] == 9


def test_fit_refuses_too_little_data():
    with pytest.raises(UserError, match="distinct"):
        fit_polynomial(np.array([10.0, 20.0]), np.array([1.0, 2.0]), 3)
    with pytest.raises(UserError, match="too few"):
        fit_steps(pd.DataFrame({"n_open": [1], "duty_pct": [50.0], "thrust_gf": [20.0]}))
    with pytest.raises(UserError, match="order-4"):
        fit_steps(pd.DataFrame({"n_open": [1] * 3, "duty_pct": [10.0, 50, 90], "thrust_gf": [1.0, 2, 4]}),
                  order=4)
    with pytest.raises(UserError, match="column"):
        fit_steps(pd.DataFrame({"duty_pct": [1.0]}))
    # three steps: only orders 1-2 are possible, and AICc is infinite: falls back to BIC
    fits = fit_orders(np.array([10.0, 50, 90]), np.array([1.0, 20, 38]))
    assert sorted(fits) == [1, 2] and select_order(fits, "aicc") in (1, 2)
