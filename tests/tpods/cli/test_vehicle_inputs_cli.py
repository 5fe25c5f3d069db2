"""``tpods estimate batch RUN --vehicle V --estimate mass,izz,cx,cy,delay,drop`` (issue 24):
a valve dead time and a shared-supply drop estimated with the body on the command line, an
uninformed drop warned about, and the one-line refusal on a run without valves."""

import json
from pathlib import Path

from tests.support.cli import run_in_process

ROOT = Path(__file__).resolve().parents[3]
EIGHT = ROOT / "vehicles" / "example-8-onoff.toml"


def _files(tmp_path: Path) -> tuple[Path, Path]:
    """``(truth, model)`` vehicle files: the truth with a 30 ms delay and a 3 % drop."""
    text = EIGHT.read_text().replace("force_sigma_n = 0.005\n", "")
    truth, model = tmp_path / "truth.toml", tmp_path / "model.toml"
    truth.write_text(text.replace("delay_s = 0.0", "delay_s = 0.03")
                     + "\n[supplies.main]\ndrop_per_valve = 0.03\n")
    model.write_text(text)
    return truth, model


def _sim(tpods_exe, truth: Path, out: Path, spec: str) -> None:
    r = run_in_process("sim", "--vehicle", str(truth), "--input", spec, "--mass", "23.09",
                "--izz", "0.31", "--duration", "40", "--seed", "4", "--out", str(out))
    assert r.returncode == 0, r.stderr


def test_delay_and_drop_estimated_on_the_command_line(tpods_exe, tmp_path):
    truth, model = _files(tmp_path)
    _sim(tpods_exe, truth, tmp_path / "run", "pulse-groups")
    r = run_in_process("estimate", "batch", str(tmp_path / "run"), "--vehicle", str(model),
                "--estimate", "mass,izz,cx,cy,delay,drop", "--json")
    assert r.returncode == 0, r.stderr
    est = json.loads(r.stdout)
    assert est["converged"] and est["estimated"] == ["mass", "izz", "cx", "cy", "delay", "drop"]
    for name, true in (("delay", 0.03), ("drop", 0.03)):
        p = est["input_params"][name]
        assert p["estimated"] and abs(p["value"] - true) < 3.5 * p["sigma"], (name, p)
        assert abs(p["sigma"] / est["crlb_sigma"][name] - 1) < 0.10
    assert abs(est["mass_kg"] - 23.09) < 3.5 * est["mass_sigma_kg"]


def test_a_run_of_single_valves_warns_that_the_drop_is_not_estimated(tpods_exe, tmp_path):
    truth, model = _files(tmp_path)
    _sim(tpods_exe, truth, tmp_path / "run", "pulses")
    r = run_in_process("estimate", "batch", str(tmp_path / "run"), "--vehicle", str(model),
                "--estimate", "mass,izz,cx,cy,delay,drop", "--json")
    assert r.returncode == 0, r.stderr
    assert "tpods: warning: drop is not estimated" in r.stderr
    est = json.loads(r.stdout)
    assert "drop" not in est["estimated"] and not est["input_params"]["drop"]["estimated"]


def test_delay_on_a_run_without_a_vehicle_is_one_line(tpods_exe, tmp_path):
    r = run_in_process("sim", "--duration", "5", "--out", str(tmp_path / "run"))
    assert r.returncode == 0, r.stderr
    r = run_in_process("estimate", "batch", str(tmp_path / "run"), "--estimate",
                "mass,izz,delay")
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and len(lines) == 1 and "--vehicle" in lines[0], r.stderr


def test_calibrate_thrust_estimates_the_centre_of_mass_when_asked(tpods_exe, tmp_path):
    truth, _ = _files(tmp_path)
    _sim(tpods_exe, truth, tmp_path / "run", "pulse-groups")
    r = run_in_process("calibrate", "thrust", str(tmp_path / "run"), "--mass", "23.09",
                "--per", "common", "--estimate-com", "--json", "--out", str(tmp_path / "cal"))
    assert r.returncode == 0, r.stderr
    cal = json.loads(r.stdout)
    assert set(cal["extras"]) == {"cx", "cy"}
    # the run folder's vehicle (delay 30 ms) is the model: its timing is applied
    assert abs(cal["factors"]["scale"]["value"] - 1.0) < 3.5 * cal["factors"]["scale"]["sigma"]
