"""Regression: the real recordings of other labs under runs/fixtures/real/ import as their
SOURCE.md says, checked where no estimation is needed: row counts, the time base, units
(against the source's own SI columns), the table's extent and the valves open per row.

- aevarofjord-air-bearing: AevarOfjord/mpc-air-bearing-satellite (MIT) at
  44b2d08b15e301305bc23a6bbacae63899440252, Data/Real_Test/Test/real_test_data.csv steps 900-1316.
- hmv-s16-motive: cmuphyscomp/hmv-s16 (BSD-3) at 7863c66ed645b463b72aef98a5c484a18cc9f396,
  python/rhinoscripts/sample_optitrack_take.csv, first 40 frames.
"""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from mocap_bridge.exports import PoseOptions, read_poses
from mocap_bridge.exports.command_log import command_keys, read_command_log
from mocap_bridge.exports.generic_csv import parse_column_map

REAL = Path(__file__).resolve().parents[2] / "runs/fixtures/real"
AEVAR = REAL / "aevarofjord-air-bearing"
CSV = AEVAR / "real_test_data_excerpt.csv"
POSE_COLUMNS = "t=Control_Time,x=Telemetry_X_mm,y=Telemetry_Z_mm,yaw=Telemetry_Yaw_deg"


@pytest.fixture(scope="module")
def source() -> pd.DataFrame:
    return pd.read_csv(CSV)


@pytest.fixture(scope="module")
def poses():
    return read_poses(CSV.read_text(), PoseOptions(columns=POSE_COLUMNS, time_unit="s"), str(CSV))


@pytest.fixture(scope="module")
def commands():
    cols = parse_column_map("t=Control_Time,valves=Command_Vector", command_keys(8))
    return read_command_log(CSV.read_text(), cols, n_valves=8, time_unit="s", what=str(CSV))


def test_every_fixture_has_its_licence_and_source():
    for d in (AEVAR, REAL / "hmv-s16-motive"):
        assert (d / "LICENSE").read_text().strip()
        src = (d / "SOURCE.md").read_text()
        assert "commit" in src and "Licence" in src


def test_air_bearing_poses_rows_time_base_and_units(poses, source):
    assert len(source) == 417
    assert poses.counts == {"frames": 417, "kept": 417, "occluded": 0, "repeated": 0}
    np.testing.assert_allclose(np.diff(poses.t_s), 0.06, atol=1e-9)  # one row per 60 ms step
    assert poses.t0_source_s == pytest.approx(54.0)
    # units: the source's own m and rad columns agree (Current_*, real.py:440-488, 616-618)
    np.testing.assert_allclose(poses.x_m, source.Current_X, atol=1e-9)
    np.testing.assert_allclose(poses.y_m, source.Current_Y, atol=1e-9)
    np.testing.assert_allclose(np.angle(np.exp(1j * (poses.psi_rad - source.Current_Yaw))), 0, atol=1e-9)
    # the table: every position within +-2.5 m
    assert np.abs(poses.x_m).max() < 2.5 and np.abs(poses.y_m).max() < 2.5


def test_air_bearing_valves_open_per_row_match_the_vector(commands, source):
    assert commands.values.shape == (418, 8)  # 417 steps and the end row
    np.testing.assert_allclose(commands.t_s - 54.0, np.arange(418) * 0.06, atol=1e-9)
    vec = np.array([json.loads(c) for c in source.Command_Vector])
    np.testing.assert_array_equal(commands.values[:-1] / 100.0, vec)
    open_per_row = (commands.values[:-1] > 0).sum(axis=1)
    np.testing.assert_array_equal(open_per_row, vec.sum(axis=1))
    assert np.bincount(open_per_row).tolist() == [123, 127, 98, 24, 45]  # as SOURCE.md states
    cols = parse_column_map("t=Control_Time,valves=Command_Hex", command_keys(8))
    bits = read_command_log(CSV.read_text(), cols, n_valves=8, form="bits", time_unit="s", what=str(CSV))
    np.testing.assert_array_equal(bits.values, commands.values)


def test_air_bearing_vehicle_file_says_what_the_source_says():
    v = tomllib.loads((AEVAR / "vehicle.toml").read_text())
    th = v["thrusters"]
    assert [t["name"] for t in th] == [f"T{i}" for i in range(1, 9)]
    assert [t["force_n"] for t in th] == [0.441450, 0.430659, 0.427716, 0.438017,
                                          0.468918, 0.446846, 0.466956, 0.484124]
    assert th[0]["position_m"] == [0.145, 0.06] and th[2]["position_m"] == [0.06, -0.145]
    assert {tuple(t["direction"]) for t in th[:2]} == {(-1.0, 0.0)}
    # the stated mass is beside it (stated.json), not a prior of the fit: the run is estimated
    # with the mass unknown and compared with it (test_real_air_bearing_estimate.py)
    assert "body" not in v
    stated = json.loads((AEVAR / "stated.json").read_text())
    assert stated["mass_kg"] == pytest.approx(7.614 + 7.724 + 7.752)
    assert "izz_kgm2" not in stated  # not measured by the source (only a cube formula)


def test_motive_export_rows_rate_and_extent():
    t = read_poses((REAL / "hmv-s16-motive/sample_optitrack_take_excerpt.csv").read_text(), PoseOptions(), "take")
    assert t.counts == {"frames": 40, "kept": 40, "occluded": 0, "repeated": 0}
    np.testing.assert_allclose(np.diff(t.t_s), 1 / 120, atol=2e-6)  # 120 Hz, times to 1 us
    assert np.ptp(t.x_m) < 1e-3 and np.ptp(t.y_m) < 1e-3  # the body lies still


# ----------------------------------------------------------------------------- the whole run's true times

WHOLE = AEVAR / "real_test_data.csv"
TIME_FROM = ["--time-from", "vx=Current_VX,x=Current_X,vy=Current_VY,y=Current_Y,wz=Current_Angular_Vel,"
             "yaw=Current_Yaw", "--time-from-units", "m,rad"]
CMD_WHOLE = ["--columns", "t=Control_Time,valves=Command_Vector", "--time-unit", "s", "--vehicle",
             str(AEVAR / "vehicle.toml")]


def _import(kind: str, out: Path, *extra: str):
    from tests.support.cli import run_in_process

    args = ["--columns", POSE_COLUMNS, "--time-unit", "s"] if kind == "poses" else CMD_WHOLE
    r = run_in_process("import", kind, str(WHOLE), "--out", str(out), *args, *extra)
    assert r.returncode == 0, r.stderr
    return r


@pytest.fixture(scope="module")
def whole_runs(tmp_path_factory):
    """The whole file: poses with --time-from then commands (mapped through the folder's
    time base), and commands with --time-from then poses (mapped)."""
    tmp = tmp_path_factory.mktemp("aevar-time-from")
    first = _import("poses", tmp / "a", *TIME_FROM), _import("commands", tmp / "a")
    second = _import("commands", tmp / "b", *TIME_FROM), _import("poses", tmp / "b")
    return {"a": (tmp / "a", first), "b": (tmp / "b", second)}


def test_whole_run_pose_times_rebuilt_from_its_velocities(whole_runs):
    run, (poses, _) = whole_runs["a"]
    assert "pose times rebuilt from the logged velocities (3063 of 3269 intervals; 206 filled" in poses.stdout
    assert "208.3 s against the nominal 196.2 s of Control_Time (+6.2 %)" in poses.stdout
    assert "jitter far beyond a stated frame rate" in poses.stderr
    tb = json.loads((run / "run.json").read_text())["time_base"]
    assert tb["nominal_span_s"] == pytest.approx(196.16)
    assert tb["rebuilt_span_s"] == pytest.approx(208.34, abs=0.02)
    assert tb["rate_difference"] == pytest.approx(0.062, abs=0.002)
    # the last 206 rows log velocities that are no finite differences (x, y and yaw disagree)
    assert tb["filled"] == {"disagree": 206} and tb["determined"] / tb["intervals"] == pytest.approx(0.937, abs=1e-3)
    assert tb["mean_interval_s"] == pytest.approx(0.0638, abs=0.0002)
    assert 0.043 < tb["determined_interval_s"]["min"] and tb["determined_interval_s"]["max"] < 0.093
    t = pd.read_csv(run / "poses.csv").t.to_numpy()
    assert len(t) == 3270 and t[0] == 0.0 and t[-1] == pytest.approx(tb["rebuilt_span_s"])
    d = np.diff(t)[:3063]  # 44-92 ms, the determined ones in steps near 1/64 s
    assert np.mean(d) == pytest.approx(0.0638, abs=0.0002)
    # dt = dX/VX exactly where the velocities are finite differences
    src = pd.read_csv(WHOLE)
    np.testing.assert_allclose(d, np.diff(src.Current_Y)[:3063] / src.Current_VY[1:3064], atol=3e-9)  # %.12g


@pytest.mark.parametrize("order", ["a", "b"])
def test_whole_run_commands_land_on_the_rebuilt_pose_times_in_either_order(whole_runs, order):
    run, _ = whole_runs[order]
    poses = pd.read_csv(run / "poses.csv")
    cmds = pd.read_csv(run / "commands.csv")
    assert len(cmds) == 3271  # 3270 rows and the end row
    np.testing.assert_allclose(cmds.t.to_numpy()[:-1], poses.t.to_numpy(), atol=1e-6)
    assert cmds.t.iloc[-1] == pytest.approx(poses.t.iloc[-1] + 0.063, abs=1e-3)
    meta = json.loads((run / "run.json").read_text())
    assert meta["time_origin_s"] == 0.0 and (run / "time_base.csv").exists()


def test_both_orders_give_the_same_files(whole_runs):
    a, b = whole_runs["a"][0], whole_runs["b"][0]
    for name in ("poses.csv", "commands.csv", "time_base.csv"):
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
