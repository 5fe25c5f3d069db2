"""Done-when: --model auto picks ideal on frictionless data and friction on data with friction
(several seeds, masses and coefficient values, not one fixture)."""

import pytest

from estimator.batch.model_select import select_model
from estimator.reports.realism import FRICTION, TRUTH, simulate_run

CASES = [
    # (truth, seed, mass, izz, expected)
    ({}, 201, 0.72, 1.2e-3, "ideal"),
    ({}, 202, 1.6, 2.5e-3, "ideal"),
    ({}, 203, 3.0, 6e-3, "ideal"),
    (FRICTION, 204, 0.72, 1.2e-3, "friction"),
    ({"ct": 0.08, "cr": 2e-4, "kb": 1e-3}, 205, 1.6, 2.5e-3, "friction"),
    ({"ct": 0.3, "cr": 1e-3, "kb": 0.0}, 206, 0.72, 1.2e-3, "friction"),
    (TRUTH, 207, 0.72, 1.2e-3, "friction+tilt"),
]


@pytest.mark.parametrize(("truth", "seed", "mass", "izz", "expected"), CASES)
def test_auto_selection(truth, seed, mass, izz, expected):
    res, cmd_t, thrust = simulate_run(truth, seed, mass_kg=mass, izz_kgm2=izz)
    sel = select_model(res.pose_t, res.pose, cmd_t, thrust)
    assert sel.chosen == expected, "\n".join(sel.table_lines())
    assert sel.reason
    chosen = sel.fits[sel.chosen]
    assert chosen.result.converged
    assert 0.9 < chosen.reduced_chi2 < 1.1
    if expected != "ideal":
        # the ideal model's residuals are far from white on data with friction
        assert max(sel.fits["ideal"].lb_q) > 10 * max(chosen.lb_q)
        assert sel.by_aic != "ideal" and sel.by_bic != "ideal"
    # the nested fits never fit worse than the smaller model
    chis = [sel.fits[m].chi2 for m in ("ideal", "friction", "friction+tilt")]
    assert chis[1] <= chis[0] * (1 + 1e-9) and chis[2] <= chis[1] * (1 + 1e-9)
