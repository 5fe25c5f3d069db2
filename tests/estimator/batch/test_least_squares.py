"""Batch least squares: statistical efficiency on simulated runs, robustness, guards."""

import math

import numpy as np
import pytest

from common.errors import UserError
from common.runfolder import read_run
from estimator.batch.crlb import crlb
from estimator.batch.least_squares import batch_ls, estimate_run, parse_window
from estimator.plant.inputs import phase_sine, translate_rotate
from estimator.plant.model import PlantParams
from estimator.plant.sim import SimConfig, simulate, write_sim_run


def _sim(mass, izz, seed, *, duration=30.0, drop=0.0, cmd_rate=50.0, pose_rate=120.0,
         omega=1.0, amplitude=20.0, s0=(0, 0, 0, 0, 0, 0), **fric):
    cmd_t, duty = phase_sine(duration, cmd_rate, amplitude, omega)
    cfg = SimConfig(pose_rate_hz=pose_rate, drop=drop, seed=seed, initial_state=s0)
    return simulate(cmd_t, duty, PlantParams(mass, izz, **fric), config=cfg)


def _check_efficient(res, sim, names=("mass", "izz")):
    """Error within 3 sigma and sigma within 20 % of the CRLB computed at the truth."""
    assert res.converged, res.message
    truth = sim.params.kwargs()
    bound = crlb(sim.pose_t, sim.cmd_t, sim.thrust_n, truth, s0=sim.config.initial_state,
                 names=names)
    for j, name in enumerate(names):
        est = res.z0[6 + j]
        sig = res.sigma[6 + j]
        assert abs(est - truth[name]) < 3 * sig, (name, est, truth[name], sig)
        assert abs(sig / bound.sigma[j] - 1) < 0.2, (name, sig, bound.sigma[j])
    # the initial state too
    np.testing.assert_array_less(np.abs(res.z0[:6] - np.asarray(sim.config.initial_state)),
                                 3 * res.sigma[:6] + 1e-12)


# several (mass, izz, seed) combinations away from the paper's values, with drops,
# 50 Hz commands against 120 Hz poses, and other rates
CASES = [
    # mass, izz, seed, drop, cmd_rate, pose_rate
    (2.268, 3.78e-3, 1, 0.0, 50.0, 120.0),
    (0.5, 1e-3, 2, 0.05, 50.0, 120.0),
    (5.0, 1e-2, 3, 0.05, 50.0, 120.0),
    (0.5, 1e-2, 4, 0.0, 30.0, 100.0),
    (5.0, 1e-3, 5, 0.05, 50.0, 120.0),
    (1.1, 6e-3, 6, 0.05, 10.0, 120.0),
]


@pytest.mark.parametrize("mass,izz,seed,drop,cmd_rate,pose_rate", CASES)
def test_efficient_on_simulated_runs(mass, izz, seed, drop, cmd_rate, pose_rate):
    sim = _sim(mass, izz, seed, drop=drop, cmd_rate=cmd_rate, pose_rate=pose_rate)
    nominal = int(30 * pose_rate) + 1
    if drop:
        assert len(sim.pose_t) < nominal - 0.02 * nominal  # frames really are missing
    res = batch_ls(sim.pose_t, sim.pose, sim.cmd_t, sim.thrust_n)  # paper's initial guess
    _check_efficient(res, sim)
    # the residuals are the noise: rms near 1 cm and 1 deg, yaw residuals wrapped
    rms = res.rms_residuals()
    assert 0.009 < rms[0] < 0.011 and 0.009 < rms[1] < 0.011
    assert math.radians(0.9) < rms[2] < math.radians(1.1)
    assert np.all(np.abs(res.residuals[:, 2]) <= math.pi)


def test_wrapped_yaw_and_mid_run_window():
    # the module spins several turns: the recorded yaw is wrapped; the window starts mid-run
    # with non-zero velocities, which the estimate recovers
    sim = _sim(1.8, 2.5e-3, 11, duration=40.0, drop=0.05, s0=(0.3, -0.2, 3.0, 0.02, -0.01, 0.5))
    assert np.ptp(sim.states[:, 2]) > 4 * math.pi
    assert np.all(np.abs(sim.pose[:, 2]) <= math.pi)
    res = batch_ls(sim.pose_t, sim.pose, sim.cmd_t, sim.thrust_n)
    _check_efficient(res, sim)
    keep = sim.pose_t >= 10.0
    res_w = batch_ls(sim.pose_t[keep], sim.pose[keep], sim.cmd_t, sim.thrust_n)
    assert res_w.converged
    true_s = sim.states[keep][0]
    dpsi = (res_w.z0[2] - true_s[2] + math.pi) % (2 * math.pi) - math.pi
    assert abs(dpsi) < 3 * res_w.sigma[2]
    np.testing.assert_array_less(np.abs(res_w.z0[3:6] - true_s[3:6]), 3 * res_w.sigma[3:6])
    assert abs(res_w.mass_kg - 1.8) < 3 * res_w.mass_sigma_kg


@pytest.mark.parametrize("factor", [0.5, 1.5])
def test_converges_from_plus_minus_50_percent(factor):
    sim = _sim(3.2, 7e-3, 21)
    ref = batch_ls(sim.pose_t, sim.pose, sim.cmd_t, sim.thrust_n)
    res = batch_ls(sim.pose_t, sim.pose, sim.cmd_t, sim.thrust_n,
                   initial={"mass": 3.2 * factor, "izz": 7e-3 * factor})
    assert res.converged and ref.converged
    # the same minimum from every start
    np.testing.assert_allclose(res.z0, ref.z0, rtol=1e-6, atol=1e-9)
    _check_efficient(res, sim)


def test_translate_rotate_input_and_friction_names():
    # the paper's experiment input with friction, estimated jointly by name
    cmd_t, duty = translate_rotate(28.0, 50.0)
    p = PlantParams(0.72, 2e-3, ct=0.15, cr=2e-4, kb=1e-3)
    sim = simulate(cmd_t, duty, p, config=SimConfig(seed=8, drop=0.05))
    names = ("mass", "izz", "ct", "cr", "kb")
    res = batch_ls(sim.pose_t, sim.pose, sim.cmd_t, sim.thrust_n, names=names,
                   initial={"mass": 1.0, "izz": 3e-3})
    _check_efficient(res, sim, names)
    assert res.names == names and res.z0.shape == (11,) and res.cov.shape == (11, 11)
    # fixing the friction at its true values instead gives a smaller sigma on the mass
    res_fixed = batch_ls(sim.pose_t, sim.pose, sim.cmd_t, sim.thrust_n,
                         fixed={"ct": 0.15, "cr": 2e-4, "kb": 1e-3})
    assert res_fixed.converged and res_fixed.mass_sigma_kg < res.mass_sigma_kg


def test_result_fields_and_covariance():
    sim = _sim(2.0, 4e-3, 31, duration=20.0)
    res = batch_ls(sim.pose_t, sim.pose, sim.cmd_t, sim.thrust_n)
    assert res.t0 == sim.pose_t[0]
    assert res.residuals.shape == (len(sim.pose_t), 3)
    np.testing.assert_allclose(res.cov, res.cov.T)
    assert np.all(np.linalg.eigvalsh(res.cov) > 0)
    np.testing.assert_allclose(res.sigma, np.sqrt(np.diag(res.cov)))
    assert res.mass_sigma_kg == res.sigma[6] and res.izz_sigma_kgm2 == res.sigma[7]
    assert res.corr_mass_izz == pytest.approx(res.cov[6, 7] / (res.sigma[6] * res.sigma[7]))
    # cost history: non-increasing within the last stage, and the final cost is chi-square-like
    last = res.cost_history[-3:]
    assert all(b <= a * (1 + 1e-12) for a, b in zip(last, last[1:], strict=False))
    dof = 3 * len(sim.pose_t) - 8
    assert abs(res.cost_history[-1] - dof) < 5 * math.sqrt(2 * dof)
    d = res.to_dict()
    assert d["mass_kg"] == res.mass_kg and d["converged"] is True


def test_iteration_cap_reports_not_converged():
    sim = _sim(2.0, 4e-3, 32, duration=15.0)
    res = batch_ls(sim.pose_t, sim.pose, sim.cmd_t, sim.thrust_n, max_iter=1, horizon0_s=None)
    assert res.converged is False and "not converged" in res.message


def test_prior_pulls_the_estimate():
    sim = _sim(2.0, 4e-3, 33, duration=10.0)
    n = 8
    zbar = np.zeros(n)
    zbar[6:] = (2.5, 4e-3)
    P = np.diag([1e4] * 6 + [1e-8, 1e-2])  # mass pinned at 2.5 kg, the rest diffuse
    res = batch_ls(sim.pose_t, sim.pose, sim.cmd_t, sim.thrust_n, prior=(zbar, P))
    assert res.converged
    assert res.mass_kg == pytest.approx(2.5, abs=1e-3)
    assert res.mass_sigma_kg < 2e-4


def test_refuses_bad_input():
    sim = _sim(2.0, 4e-3, 34, duration=5.0)
    a = (sim.pose_t, sim.pose, sim.cmd_t, sim.thrust_n)
    bad_pose = sim.pose.copy()
    bad_pose[3, 0] = np.nan
    with pytest.raises(UserError, match="NaN"):
        batch_ls(a[0], bad_pose, a[2], a[3])
    with pytest.raises(UserError, match=r"\(N, 3\)"):
        batch_ls(a[0], a[1][:, :2], a[2], a[3])
    with pytest.raises(UserError, match="increase"):
        batch_ls(a[0][::-1], a[1], a[2], a[3])
    with pytest.raises(UserError, match="names"):
        batch_ls(*a, names=("mass", "volume"))
    with pytest.raises(UserError, match="neither estimated nor given"):
        batch_ls(*a, names=("izz",))
    with pytest.raises(UserError, match="cannot determine"):
        batch_ls(a[0][:2], a[1][:2], a[2], a[3])
    with pytest.raises(UserError, match="initial mass must be positive"):
        batch_ls(*a, initial={"mass": -1.0})
    with pytest.raises(UserError, match="window"):
        parse_window("5")
    with pytest.raises(UserError, match="window"):
        parse_window("9:3")


def test_estimate_run_on_a_run_folder(tmp_path):
    sim = _sim(1.4, 3e-3, 35, duration=20.0, drop=0.05)
    write_sim_run(sim, tmp_path / "run")
    run = read_run(tmp_path / "run")
    res = estimate_run(run, window="2:18")
    assert res.converged and res.t[0] >= 2.0 and res.t[-1] <= 18.0
    assert abs(res.mass_kg - 1.4) < 3 * res.mass_sigma_kg
    with pytest.raises(UserError, match="fewer than 2"):
        estimate_run(run, window="100:200")


def test_no_torque_gives_an_infinite_izz_sigma_without_numpy_warnings():
    """The first 6 s of the translate-then-rotate input hold no torque: Izz has no
    information. The fit says so (sigma inf); to_dict used to leak a numpy 'invalid value'
    RuntimeWarning onto the user's terminal (inf / inf in the correlation matrix)."""
    import warnings

    cmd_t, duty = translate_rotate(6.0, 50.0)
    sim = simulate(cmd_t, duty, PlantParams(1.5, 6e-3), config=SimConfig(seed=3))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        res = batch_ls(sim.pose_t, sim.pose, sim.cmd_t, sim.thrust_n)
        d = res.to_dict()
    assert math.isinf(d["izz_sigma_kgm2"]) and math.isfinite(d["mass_sigma_kg"])
    assert abs(d["mass_kg"] - 1.5) < 3 * d["mass_sigma_kg"]


# issue 16: plausibility, said out loud

def _run_folder(tmp_path, name, edit_poses=None, close_valves=False):
    import pandas as pd

    cmd_t, duty = phase_sine(20.0, 50.0)
    sim = simulate(cmd_t, duty, PlantParams(3.1, 6.5e-3), config=SimConfig(seed=5, drop=0.02))
    d = write_sim_run(sim, tmp_path / name)
    if edit_poses is not None:
        p = pd.read_csv(d / "poses.csv")
        edit_poses(p).to_csv(d / "poses.csv", index=False)
    if close_valves:
        c = pd.read_csv(d / "commands.csv")
        c[[k for k in c.columns if k != "t"]] = 0
        c.to_csv(d / "commands.csv", index=False)
    return read_run(d)


def test_plausible_residuals_give_no_warning(tmp_path):
    res = estimate_run(_run_folder(tmp_path, "ok"))
    assert res.converged and res.warnings == [] and "warnings" not in res.to_dict()


def test_poses_in_millimetres_warn_naming_the_cause(tmp_path):
    run = _run_folder(tmp_path, "mm", lambda p: p.assign(x=p.x * 1000, y=p.y * 1000))
    res = estimate_run(run)
    assert any("position residuals" in w and "millimetres" in w for w in res.warnings)
    assert res.to_dict()["warnings"] == res.warnings


def test_yaw_in_degrees_warns_naming_the_cause(tmp_path):
    run = _run_folder(tmp_path, "deg", lambda p: p.assign(psi=np.degrees(p.psi)))
    res = estimate_run(run)
    assert any("yaw residuals" in w and "yaw in degrees instead of radians?" in w
               for w in res.warnings)


def test_singular_normal_equations_are_a_user_error_not_a_traceback(monkeypatch):
    import estimator.batch.least_squares as ls

    def broken(*a, **k):
        raise np.linalg.LinAlgError("Singular matrix")

    monkeypatch.setattr(ls, "_lm", broken)
    cmd_t, duty = phase_sine(5.0, 50.0)
    sim = simulate(cmd_t, duty, PlantParams(3.1, 6.5e-3), config=SimConfig(seed=5))
    with pytest.raises(UserError, match="yaw in degrees instead of radians"):
        batch_ls(sim.pose_t, sim.pose, sim.cmd_t, sim.thrust_n)


def test_all_valves_closed_is_not_converged_and_says_why(tmp_path):
    res = estimate_run(_run_folder(tmp_path, "closed", close_valves=True))
    assert not res.converged
    assert res.message.startswith("not converged: mass, izz have no information")
    assert "no thrust: every valve is closed" in res.message


def test_no_torque_is_not_converged_naming_izz():
    from estimator.batch.least_squares import no_information

    cmd_t, duty = translate_rotate(6.0, 50.0)
    sim = simulate(cmd_t, duty, PlantParams(1.5, 6e-3), config=SimConfig(seed=3))
    res = batch_ls(sim.pose_t, sim.pose, sim.cmd_t, sim.thrust_n)
    why = no_information(res.names, res.sigma, sim.thrust_n)
    assert why.startswith("izz has no information") and "no torque" in why
