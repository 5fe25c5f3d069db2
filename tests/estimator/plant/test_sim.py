import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from common.errors import UserError
from common.runfolder import read_run
from common.thrust_table import ThrustTable
from estimator.plant.inputs import make_input, phase_sine, translate_rotate
from estimator.plant.model import PlantParams, dynamics, wrap_angle
from estimator.plant.sim import SimConfig, simulate, write_sim_run


def _reference(cmd_t, thrust, t_out, p: PlantParams):
    """Independent solution: DOP853 at tight tolerance, restarted at every switch."""
    kw = p.kwargs()
    cur = np.zeros(6)
    out = [cur]
    for j in range(len(cmd_t) - 1):
        a, b = cmd_t[j], cmd_t[j + 1]
        ts = t_out[(t_out > a) & (t_out <= b)]
        te = np.union1d(ts, [b])
        sol = solve_ivp(lambda _t, x, T=thrust[j]: dynamics(x, T, **kw), (a, b), cur, t_eval=te,
                        rtol=1e-12, atol=1e-13, method="DOP853")
        cur = sol.y[:, -1]
        out.extend(sol.y.T[np.isin(te, ts)])
    return np.array(out)


@pytest.mark.parametrize("kind,params", [
    ("phase-sine", PlantParams(2.268, 3.78e-3)),
    ("translate-rotate", PlantParams(0.72, 1.9e-3, ct=0.2, cr=1e-3, kb=2e-3, ax=0.002)),
])
def test_noise_free_poses_match_independent_solution(kind, params):
    # 40 s: 2000 switches at 50 Hz (the reference restarts DOP853 at each: 120 s took 15 s)
    cmd_t, duty = make_input(kind, 40.0, 50.0)
    res = simulate(cmd_t, duty, params, config=SimConfig(noise_pos_m=0, noise_yaw_rad=0))
    ref = _reference(cmd_t, ThrustTable.default().thrust_n(duty), res.pose_t, params)
    assert len(res.pose_t) == 4801
    assert np.abs(res.pose[:, :2] - ref[:, :2]).max() < 1e-6
    dpsi = wrap_angle(res.pose[:, 2] - ref[:, 2])
    assert np.abs(dpsi).max() < 1e-6
    assert np.abs(res.states - ref).max() < 1e-6


def test_commands_switch_between_pose_times():
    # 7 Hz commands against 120 Hz poses: switches never align with frames
    cmd_t, duty = phase_sine(10.0, 7.0)
    p = PlantParams(1.3, 6e-3)
    res = simulate(cmd_t, duty, p, config=SimConfig(noise_pos_m=0, noise_yaw_rad=0))
    ref = _reference(cmd_t, ThrustTable.default().thrust_n(duty), res.pose_t, p)
    assert np.abs(res.states - ref).max() < 1e-8


def test_noise_drop_and_wrapping():
    cmd_t, duty = phase_sine(60.0, 50.0)
    cfg = SimConfig(noise_pos_m=0.01, noise_yaw_rad=math.radians(1), drop=0.2, seed=3)
    res = simulate(cmd_t, duty, PlantParams(2.268, 3.78e-3), config=cfg)
    n_nom = 60 * 120 + 1
    assert 0.75 * n_nom < len(res.pose_t) < 0.85 * n_nom
    assert res.pose_t[0] == 0.0
    err = res.pose[:, :2] - res.states[:, :2]
    assert abs(err.std() - 0.01) < 0.0005
    assert np.all(res.pose[:, 2] > -math.pi) and np.all(res.pose[:, 2] <= math.pi)
    assert np.abs(res.states[:, 2]).max() > math.pi  # the module spins: wrapping was exercised
    yerr = wrap_angle(res.pose[:, 2] - res.states[:, 2])
    assert abs(yerr.std() - math.radians(1)) < math.radians(0.05)
    # same seed, same run
    res2 = simulate(cmd_t, duty, PlantParams(2.268, 3.78e-3), config=cfg)
    np.testing.assert_array_equal(res.pose, res2.pose)


def test_translate_rotate_pattern():
    t, d = translate_rotate(14.0, 50.0)
    row = lambda tt: d[np.searchsorted(t, tt, side="right") - 1]  # noqa: E731
    np.testing.assert_array_equal(row(0.5), [25, 25, 0, 0])
    np.testing.assert_array_equal(row(1.5), [0, 0, 25, 25])
    np.testing.assert_array_equal(row(7.2), [15, 0, 15, 0])
    np.testing.assert_array_equal(row(7.7), [0, 15, 0, 15])
    np.testing.assert_array_equal(d[-1], [0, 0, 0, 0])
    assert t[-1] == 14.0


def test_phase_sine_definition():
    t, d = phase_sine(10.0, 50.0, amplitude_pct=20, omega_rad_s=1.0)
    i = 123
    expect = 50 + 20 * np.sin(t[i] + np.arange(4) * np.pi / 4)
    np.testing.assert_allclose(d[i], expect)


def test_written_run_is_valid(tmp_path):
    cmd_t, duty = phase_sine(5.0, 50.0)
    res = simulate(cmd_t, duty, PlantParams(1.0, 2e-3), config=SimConfig(drop=0.05, seed=1))
    p = write_sim_run(res, tmp_path / "r", "phase-sine")
    r = read_run(p)
    np.testing.assert_allclose(r.pose, res.pose, atol=1e-10)
    np.testing.assert_allclose(r.duty_pct, duty, atol=1e-9)
    assert r.truth["mass_kg"] == 1.0 and r.truth["izz_kgm2"] == 2e-3
    truth = np.loadtxt(p / "truth.csv", delimiter=",", skiprows=1)
    assert truth.shape == (len(res.pose_t), 7)


def test_bad_settings_refused():
    cmd_t, duty = phase_sine(5.0, 50.0)
    with pytest.raises(UserError):
        simulate(cmd_t, duty, PlantParams(-1.0, 2e-3))
    with pytest.raises(UserError):
        simulate(cmd_t, duty, PlantParams(1.0, 2e-3), config=SimConfig(drop=1.0))
    with pytest.raises(UserError, match="outside"):
        simulate(cmd_t, duty + 25, PlantParams(1.0, 2e-3))
