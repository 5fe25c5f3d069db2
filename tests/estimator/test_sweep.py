"""A small version of the issue-17 sweep (estimator.reports.sweep): every method's final
error within 4 sigma or flagged, and no unflagged run beyond 6 sigma. The full 300-run
sweep is ``tpods report sweep --runs 300`` / ``make bench-long`` (benchmarks/bench_sweep.py)."""

from __future__ import annotations

import math

import pytest

from common.errors import UserError
from estimator.reports.sweep import SWEEP_METHODS, draw_cases, run_sweep

RUNS = 24


@pytest.fixture(scope="module")
def sweep():
    return run_sweep(RUNS, seed=17, duration_s=(20.0, 30.0))


def test_draws_are_reproducible_and_in_range():
    a, b = draw_cases(50, 3), draw_cases(50, 3)
    assert a == b and draw_cases(50, 4) != a
    for c in a:
        assert 0.3 <= c.mass_kg <= 8 and 5e-4 <= c.izz_kgm2 <= 5e-2
        assert 20 <= c.duration_s <= 120 and 0 <= c.drop <= 0.3
        assert 0.5e-3 <= c.noise_pos_m <= 5e-3
        assert math.radians(0.2) <= c.noise_yaw_rad <= math.radians(2.0) + 1e-12
    assert {c.input for c in a} == {"phase-sine", "translate-rotate"}
    with pytest.raises(UserError):
        run_sweep(1, methods=("nope",))


def test_every_method_is_within_4_sigma_or_flagged(sweep):
    s = sweep.summary()
    assert set(s) == set(SWEEP_METHODS)
    for method, r in s.items():
        assert r["runs"] == RUNS
        bad = [(row["index"], row["z_mass"], row["z_izz"]) for row in sweep.rows
               if row["method"] == method and row["z_max"] > 4 and not row["flagged"]]
        assert not bad, (method, bad)
        assert r["beyond_6sigma_unflagged"] == 0
        assert r["within_4sigma"] >= RUNS - 1, (method, r)
    assert "| ekf |" in sweep.markdown()
    d = sweep.to_dict()
    assert len(d["rows"]) == RUNS * len(SWEEP_METHODS) and d["summary"]["ekf"]["runs"] == RUNS
