"""The demo's check fit with the true thrust table (:mod:`tpods.demo.fit`): at the plant's own
valve switch times its noise-only sigma (the run's CRLB) covers the error, which a few lab
milliseconds of valve lag behind the player's stamps do not allow on a spinning module."""

from __future__ import annotations

import math

import numpy as np

from common.runfolder import Run
from estimator.batch.crlb import crlb
from estimator.plant.inputs import phase_sine
from estimator.plant.model import PlantParams, integrate_zoh
from tpods.demo.fit import batch_row, save_switches, switch_run
from tpods.demo.stages import plant_table

T0_LAB_S = 1795704722.3649786  # a lab clock's epoch seconds: 9 digits would keep 10 s


def test_switches_keep_their_times_to_the_microsecond_on_the_run_time_base(tmp_path):
    t = np.array([0.198766232, 0.218685150, 0.218685150, 0.238750461])
    duty = [(50, 64.1421, 70, 64.1421), (50.4, 64.4, 70, 63.9), (50.8, 64.7, 70, 63.6),
            (51.2, 65.0, 70, 63.3)]
    path = tmp_path / "switches.csv"
    save_switches(path, [(T0_LAB_S + tk, d) for tk, d in zip(t, duty, strict=True)], T0_LAB_S)
    assert path.read_text().splitlines()[0] == "t,d1,d2,d3,d4"
    run = Run(path=tmp_path, cmd_t=np.array([0.0]), duty_pct=np.zeros((1, 4)),
              pose_t=np.array([0.0, 1.0]), pose=np.zeros((2, 3)))
    sw = switch_run(run, path)
    # of the two rows at the same time the last holds (the plant's zero-order hold)
    np.testing.assert_allclose(sw.cmd_t, t[[0, 1, 3]], atol=1e-6)
    np.testing.assert_allclose(sw.duty_pct, np.asarray(duty)[[0, 2, 3]])


def test_true_table_fit_at_the_plant_switch_times_is_within_its_crlb_sigma(tmp_path):
    duration_s = 60.0
    cmd_t, duty = phase_sine(duration_s)
    table = plant_table()  # one weak thruster: the module spins up (Izz sigma ~1e-7)
    rng = np.random.default_rng(7)
    # the emulated valves follow the player's stamps (commands.csv) late, by ~1 lab ms
    t_sw = cmd_t + np.abs(rng.normal(0.0, 1e-3, len(cmd_t)))
    t_sw = np.maximum.accumulate(t_sw)
    truth = PlantParams(2.268, 3.78e-3)
    pose_t = np.arange(1, int(duration_s * 120)) / 120.0
    states = integrate_zoh(np.zeros(6), np.concatenate([[0.0], t_sw]),
                           np.vstack([np.zeros(4), table.thrust_n(duty, clamp=True)]),
                           np.concatenate([[0.0], pose_t]), truth)[1:]
    pose = states[:, :3] + rng.normal(0.0, 1.0, (len(pose_t), 3)) * [0.01, 0.01, math.radians(1)]
    run = Run(path=tmp_path, cmd_t=cmd_t, duty_pct=duty, pose_t=pose_t, pose=pose)
    save_switches(tmp_path / "switches.csv",
                  [(T0_LAB_S + t, d) for t, d in zip(t_sw, duty, strict=True)], T0_LAB_S)

    stamps = batch_row(run, table)
    exact = batch_row(switch_run(run, tmp_path / "switches.csv"), table)
    bound = crlb(pose_t, *run.thrust_profile(table, clamp=True),
                 {"mass": truth.mass_kg, "izz": truth.izz_kgm2}, s0=states[0])
    for row in (stamps, exact):  # the sigma is the run's CRLB (noise only: no table uncertainty)
        assert row["converged"]
        assert abs(row["izz_sigma_kgm2"] / bound.izz_sigma_kgm2 - 1) < 0.05
    # at the player's stamps the lag alone biases Izz by many sigma (the residuals look fine);
    # at the plant's own switch times the sigma covers the error
    assert abs(stamps["izz_kgm2"] - truth.izz_kgm2) > 5 * stamps["izz_sigma_kgm2"]
    assert abs(exact["izz_kgm2"] - truth.izz_kgm2) < 3 * exact["izz_sigma_kgm2"]
    assert abs(exact["mass_kg"] - truth.mass_kg) < 3 * exact["mass_sigma_kg"]
