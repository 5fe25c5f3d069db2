"""The command line of vehicle runs (issue 24): tpods sim --vehicle, estimate batch on the
run folder, the shared --structure/--vehicle option and the one-line refusals."""

import json
from pathlib import Path

import pytest

from tests.support.cli import run_in_process

ROOT = Path(__file__).resolve().parents[3]
EIGHT = ROOT / "vehicles" / "example-8-onoff.toml"


def test_sim_and_estimate_batch_on_the_command_line(tpods_exe, tmp_path):
    out = tmp_path / "run"
    r = run_in_process("sim", "--vehicle", str(EIGHT), "--input", "pulses", "--mass", "23.09",
                "--izz", "0.31", "--duration", "40", "--seed", "3", "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert (out / "vehicle.toml").is_file()
    assert (out / "commands.csv").read_text().splitlines()[0] == "t,d1,d2,d3,d4,d5,d6,d7,d8"
    assert json.loads((out / "run.json").read_text())["settings"]["vehicle"]["name"] == "example-8-onoff"
    r = run_in_process("estimate", "batch", str(out), "--initial", "m=15,izz=0.2", "--json")
    assert r.returncode == 0, r.stderr
    est = json.loads(r.stdout)
    assert est["converged"] and est["structure"] == est["vehicle"] == "example-8-onoff"
    assert abs(est["mass_kg"] - 23.09) < 3.5 * est["mass_sigma_kg"]
    # the valves' bench-force sigmas are the thrust part of sigma, each named
    assert "T1:force" in json.dumps(est)
    r = run_in_process("estimate", "batch", str(out), "--structure", str(EIGHT), "--vehicle",
                str(EIGHT))
    assert r.returncode == 2 and "not allowed with argument" in r.stderr


@pytest.mark.parametrize("args, words", [
    # estimate live takes a vehicle now (tests/estimator/live/test_vehicle_live.py); its EKF
    # alone is refused as a structure's is
    (("estimate", "live", "--method", "ekf"), "--vehicle is estimated with --method ls-ekf only"),
    # run plant and run play take a vehicle now (tests/tpods/test_plant_vehicle.py): their
    # checks of a vehicle's options, in one line, before anything starts
    (("run", "plant", "--thrust-table", str(ROOT / "common" / "data" / "table2_60psi.toml")),
     "--thrust-table would be ignored"),
    (("run", "play", "--valves", "x", "--input", "pulses", "--duty-limits", "20,90"),
     "--input pulses: open duties span 100..100 %, outside --duty-limits 20,90"),
    # a module's default typed out is the user's choice, not the vehicle's default
    (("run", "play", "--valves", "x", "--input", "pulses", "--duty-limits", "10,90"),
     "--input pulses: open duties span 100..100 %, outside --duty-limits 10,90"),
])
def test_commands_without_vehicles_refuse_in_one_line(tpods_exe, args, words):
    r = run_in_process(*args, "--vehicle", str(EIGHT))
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and len(lines) == 1 and words in lines[0], r.stderr


def test_a_structure_option_given_a_vehicle_file_reads_it_as_a_vehicle(tpods_exe, tmp_path):
    r = run_in_process("sim", "--structure", str(ROOT / "vehicles" / "tpods.toml"),
                "--duration", "5", "--out", str(tmp_path / "run"))
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "run" / "vehicle.toml").is_file()


@pytest.mark.parametrize("args", [("estimate", "live"), ("run", "plant"),
                                  ("run", "play", "--valves", "x")])
def test_live_commands_refuse_a_structure_with_a_vehicle_module_in_one_line(tpods_exe, tmp_path,
                                                                             args):
    (tmp_path / "sat.toml").write_text(EIGHT.read_text())
    (tmp_path / "s.toml").write_text('name = "s"\n[[modules]]\nname = "sat"\n'
                                     'position_m = [0.0, 0.0]\nvehicle = "sat.toml"\n')
    r = run_in_process(*args, "--structure", str(tmp_path / "s.toml"))
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and len(lines) == 1, r.stderr
    assert "a structure with a vehicle module is not run live yet" in lines[0]
