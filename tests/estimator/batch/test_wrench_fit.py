"""A wrench input (issue 24, wrench.csv ``t,fx,fy,mz``, frame body or lab): read by
common/runfolder.py and estimated by batch LS."""

from __future__ import annotations

import json

import numpy as np
import pytest

from common.errors import UserError
from common.layout import module_wrench_1
from common.runfolder import read_run, write_run
from common.runwriter import CsvLog
from estimator.estimate import estimate_run
from estimator.plant.inputs import phase_sine
from estimator.plant.model import PlantParams
from estimator.plant.sim import SimConfig, simulate

TRUTH = (2.268, 3.78e-3)


@pytest.fixture(scope="module")
def sim():
    cmd_t, duty = phase_sine(30.0)
    return simulate(cmd_t, duty, PlantParams(*TRUTH), None, SimConfig(seed=11))


def _write_wrench(folder, t, w, frame=None):
    with CsvLog(folder / "wrench.csv", ("t", "fx", "fy", "mz"), "%.12g", flush_every_s=None) as log:
        log.write_many(np.column_stack([t, w]))
    meta = {"truth": {"mass_kg": TRUTH[0], "izz_kgm2": TRUTH[1]}}
    if frame is not None:
        meta["wrench_frame"] = frame
    (folder / "run.json").write_text(json.dumps(meta))


def test_a_body_frame_wrench_estimates_as_its_thrusts(tmp_path, sim):
    given = write_run(tmp_path / "thrusts", thrust_t=sim.cmd_t, thrust_n=sim.thrust_n,
                      pose_t=sim.pose_t, pose=sim.pose)
    wrench = write_run(tmp_path / "wrench", pose_t=sim.pose_t, pose=sim.pose)
    (wrench / "commands.csv").unlink(missing_ok=True)
    _write_wrench(wrench, sim.cmd_t, sim.thrust_n @ module_wrench_1().T)
    run = read_run(wrench)
    assert run.wrench_frame == "body" and run.duty_pct is None
    t, virt = run.thrust_profile()
    assert np.array_equal(t, sim.cmd_t)
    assert np.allclose(virt @ module_wrench_1().T, sim.thrust_n @ module_wrench_1().T, atol=1e-12)
    a = estimate_run(given, None).to_dict()
    b = estimate_run(wrench, None).to_dict()
    assert b["mass_kg"] == pytest.approx(a["mass_kg"], rel=1e-6)
    assert b["izz_kgm2"] == pytest.approx(a["izz_kgm2"], rel=1e-6)
    assert b["mass_sigma_kg"] == pytest.approx(a["mass_sigma_kg"], rel=1e-6)


def test_a_lab_frame_wrench_is_turned_by_the_measured_yaw(tmp_path, sim):
    # the testbed logs the realised force in the table frame at every pose
    rows = np.searchsorted(sim.cmd_t, sim.pose_t, side="right") - 1
    body = sim.thrust_n[np.minimum(rows, len(sim.cmd_t) - 2)] @ module_wrench_1().T
    psi = sim.states[:, 2]
    lab = body.copy()
    lab[:, 0] = np.cos(psi) * body[:, 0] - np.sin(psi) * body[:, 1]
    lab[:, 1] = np.sin(psi) * body[:, 0] + np.cos(psi) * body[:, 1]
    folder = write_run(tmp_path / "lab", pose_t=sim.pose_t, pose=sim.pose)
    (folder / "commands.csv").unlink(missing_ok=True)
    _write_wrench(folder, sim.pose_t, lab, frame="lab")
    run = read_run(folder)
    assert run.wrench_frame == "lab"
    est = estimate_run(folder, None).to_dict()
    assert est["converged"]
    assert abs(est["mass_kg"] - TRUTH[0]) < 3.5 * est["mass_sigma_kg"]
    assert abs(est["izz_kgm2"] - TRUTH[1]) < 3.5 * est["izz_sigma_kgm2"]


def test_bad_wrench_runs_are_one_line(tmp_path, sim):
    folder = write_run(tmp_path / "bad", pose_t=sim.pose_t, pose=sim.pose)
    _write_wrench(folder, sim.cmd_t, np.zeros((len(sim.cmd_t), 3)), frame="table")
    with pytest.raises(UserError, match='wrench_frame must be "body" or "lab", got \'table\''):
        read_run(folder)
    write_run(folder, thrust_t=sim.cmd_t, thrust_n=sim.thrust_n, pose_t=sim.pose_t, pose=sim.pose)
    with pytest.raises(UserError, match="both wrench.csv and thrusts.csv"):
        read_run(folder)
