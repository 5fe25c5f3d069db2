"""Input design (D-optimal, workspace bound) and the orbit-follower controller."""

import math

import numpy as np
import pytest

from common.errors import UserError
from common.thrust_table import ThrustTable
from estimator.batch.design import (
    DesignSettings,
    SineInput,
    evaluate_commands,
    evaluate_sine,
    search,
)
from estimator.plant.controller import (
    InverseTable,
    OrbitFollower,
    allocate,
    geometry_matrix,
    run_orbit_follower,
)
from estimator.plant.inputs import translate_rotate
from estimator.plant.model import PlantParams

TABLE = ThrustTable.default()


def test_design_improves_log_det_over_the_papers_input_inside_the_table():
    settings = DesignSettings(duration_s=20.0, cmd_rate_hz=25.0, pose_rate_hz=60.0)
    res = search(TABLE, settings, n_random=10, n_refine=1, refine_evals=12, seed=1)
    assert res.evaluated == 1 + 10 + len(res.history) - 10
    best, paper = res.best, res.paper
    assert best.feasible
    assert max(best.excursion_m) <= 1.0
    assert best.logdet > paper.logdet + 1.0  # a clearly better D-optimal criterion
    # the best is the largest feasible score seen
    assert best.logdet == max(e.logdet for e in res.history if e.feasible)
    # duties stay in the table's valid range and the sequence re-scores identically
    open_ = best.duty_pct[:-1]
    assert open_.min() >= 10.0 - 1e-9 and open_.max() <= 90.0 + 1e-9
    again = evaluate_commands(best.cmd_t, best.duty_pct, TABLE, settings)
    assert again.logdet == pytest.approx(best.logdet, rel=1e-12)


def test_workspace_bound_is_enforced():
    # the paper's sine drifts more than a metre in 30 s: infeasible on a 2 m table
    paper = evaluate_sine(SineInput.paper(), TABLE, DesignSettings(duration_s=30.0))
    assert max(paper.excursion_m) > 1.0 and not paper.feasible and paper.score == -math.inf
    big = evaluate_sine(SineInput.paper(), TABLE,
                        DesignSettings(duration_s=30.0, table_size_m=(10.0, 10.0)))
    assert big.feasible and big.logdet == pytest.approx(paper.logdet)
    with pytest.raises(UserError, match="valid range"):
        evaluate_sine(SineInput(45.0, 1.0, (0, 0, 0, 0)), TABLE, DesignSettings(duration_s=5.0))


def test_translation_only_input_is_poorly_informative_on_izz():
    # the paper's Fig. 6a point: a translation-only input says little about Izz
    s = DesignSettings(duration_s=7.0, table_size_m=(10, 10))
    cmd_t, duty = translate_rotate(7.0, 50.0)  # first 7 s: pure y translation
    tr = evaluate_commands(cmd_t, duty, TABLE, s)
    sine = evaluate_sine(SineInput.paper(), TABLE, s)
    assert tr.crlb.izz_sigma_kgm2 / 3.78e-3 > 100 * sine.crlb.izz_sigma_kgm2 / 3.78e-3


def test_allocation_realises_the_wrench_with_nonnegative_thrusts():
    rng = np.random.default_rng(0)
    B = geometry_matrix()
    for _ in range(50):
        w = rng.normal(0, [0.1, 0.1, 0.005])
        t = allocate(w)
        assert t.min() == pytest.approx(0.0, abs=1e-15)
        np.testing.assert_allclose(B @ t, w, atol=1e-12)


def test_inverse_table_round_trip():
    inv = InverseTable(TABLE)
    for k in (1, 2, 3, 4):
        want = np.zeros(4)
        want[:k] = np.linspace(inv.t_min(k) * 1.5, inv.t_max(k) * 0.9, k)
        duty = inv.duties(want)
        assert np.count_nonzero(duty) == k
        np.testing.assert_allclose(TABLE.thrust_n(duty[None])[0], want, rtol=1e-4, atol=1e-7)
    assert np.all(inv.duties(np.zeros(4)) == 0)


def test_orbit_follower_tracks_its_setpoint_and_holds_yaw():
    ctl = OrbitFollower()
    cmd_t, duty, states = run_orbit_follower(60.0, PlantParams(2.268, 3.78e-3), TABLE, ctl)
    assert cmd_t[-1] == 60.0 and np.all(duty[-1] == 0)
    assert np.all((duty == 0) | ((duty >= 10) & (duty <= 90)))
    late = cmd_t[:-1] > 20
    sp = np.array([ctl.setpoint(t)[0] for t in cmd_t[:-1][late]])
    err = np.hypot(*(states[:-1][late, :2] - sp).T)
    assert err.max() < 0.02  # within 2 cm of a 10 cm orbit
    assert np.abs(states[:, 2]).max() < 0.02  # yaw held near zero
    assert np.ptp(states[:, 0]) > 0.15  # it does move along the orbit


def test_yaw_rate_limit_makes_a_spinning_input_infeasible():
    s = DesignSettings(duration_s=10.0, table_size_m=(10, 10))
    free = evaluate_sine(SineInput.paper(), TABLE, s)
    r_max = float(np.abs(free.crlb.states[:, 5]).max())
    assert free.feasible and r_max > 0.1
    s.max_yaw_rate_rad_s = 0.5 * r_max
    assert not evaluate_sine(SineInput.paper(), TABLE, s).feasible
