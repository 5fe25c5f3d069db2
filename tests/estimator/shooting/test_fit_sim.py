"""The segment fit on simulated vehicle runs made by the plant's own exact integrator."""

import math

import numpy as np
import pytest

from estimator.batch.least_squares import batch_ls
from estimator.shooting.fit import fit_segments
from estimator.shooting.inputs import vehicle_channels
from estimator.shooting.problem import ShootingProblem
from estimator.shooting.segments import plan_segments
from tests.estimator.shooting.simruns import sim_run, vehicle

SIG = dict(sigma_pos_m=0.003, sigma_yaw_rad=math.radians(0.3))


@pytest.fixture(scope="module")
def clean_run():
    return sim_run(7, 60.0)


def test_segments_and_single_shooting_agree(clean_run):
    """On a run the model describes, the segments chosen from the data and the toolkit's single shooting (the
    paper's Algorithm 1, :func:`batch_ls`, growing horizon) give the same mass and Izz
    within 0.3 sigma, both within 3 sigma of the truth."""
    pt, p, ct, d = clean_run
    names = ("mass", "izz", "cx", "cy")
    seg = fit_segments(pt, p, vehicle(), ct, d, names=names, length_s=None, **SIG)
    assert seg.plan.length_s >= 20.0  # a clean run: long segments chosen
    thrust_t, virtual = vehicle().input_profile(ct, d)
    one = batch_ls(pt, p, thrust_t, virtual, names=names, initial={"mass": 20.0, "izz": 0.3},
                   **SIG)
    assert seg.converged and one.converged
    for n, truth in (("mass", 23.09), ("izz", 0.31)):
        s = seg.sigma[n]["total"]
        assert abs(seg.values[n] - one.params[n]) < 0.3 * s, n
        assert abs(seg.values[n] - truth) < 3 * s, n
    # white noise, 2 segments: the total is the noise sigma (too few segments to cluster)
    sm = seg.sigma["mass"]
    assert seg.sigma_note and math.sqrt(sm["total"] ** 2 - sm["thrust"] ** 2) < 2 * sm["noise"]


def test_clustered_sigma_is_the_noise_sigma_on_white_noise(clean_run):
    pt, p, ct, d = clean_run
    seg = fit_segments(pt, p, vehicle(), ct, d, names=("mass", "izz", "cx", "cy"), length_s=3.0,
                       **SIG)
    assert not seg.sigma_note
    assert 0.6 < seg.sigma["mass"]["clustered"] / seg.sigma["mass"]["noise"] < 1.6


def test_jacobian_matches_central_differences(clean_run):
    pt, p, ct, d = clean_run
    v = vehicle()
    plan = plan_segments(pt, p, 5.0)
    names = ("mass", "izz", "cx", "ax", "delay")
    prob = ShootingProblem(pt, p, plan, vehicle_channels(v, ct, d), names, {}, np.array([0.003, 0.003, 0.005]))
    s0 = prob.initial_states()
    theta = np.array([math.log(20.0), math.log(0.3), 0.01, 1e-3, 0.05])
    r, Js, Jg = prob.jacobian(s0, theta)
    for j, h in ((0, 1e-4), (3, 0.02), (4, 2e-3)):
        up, dn = theta.copy(), theta.copy()
        up[j] += h
        dn[j] -= h
        ref = (prob.residuals(s0, up)[0] - prob.residuals(s0, dn)[0]) / (2 * h)
        assert np.allclose(Jg[:, j], ref, rtol=2e-3, atol=1e-3 * np.max(np.abs(ref))), names[j]
    s1 = s0.copy()
    s1[2, 3] += 1e-4
    ref = (prob.residuals(s1, theta)[0] - r) / 1e-4
    rows = slice(prob.row_start[2], prob.row_start[3])
    assert np.allclose(Js[rows, 3], ref[rows], rtol=1e-2, atol=1e-6)
    assert not np.any(ref[: prob.row_start[2]]) and not np.any(ref[prob.row_start[3]:])


def test_whole_run_with_tilt_drag_and_dead_time():
    """Effects single shooting cannot hold over minutes: the fit by segments with tilt,
    damping and the dead time estimated finds the mass within 3 total sigma."""
    pt, p, ct, d = sim_run(3, 120.0, tilt=(0.003, -0.002), friction=(0.4, 0.003, 0.0),
                           delay_s=0.08)
    f = fit_segments(pt, p, vehicle(), ct, d, names=("mass", "izz", "cx", "cy", "ax", "ay",
                                                     "ct", "cr", "delay"), length_s=None, **SIG)
    assert f.converged
    assert abs(f.values["mass"] - 23.09) < 3 * f.sigma["mass"]["total"]
    assert abs(f.values["delay"] - 0.08) < 3 * f.sigma["delay"]["total"] + 1e-3
    assert abs(f.values["ax"] - 0.003) < 3 * f.sigma["ax"]["total"]
