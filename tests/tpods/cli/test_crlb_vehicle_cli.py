"""``tpods estimate crlb RUN --vehicle V --estimate mass,izz,cx,cy,delay,drop`` (issue 24): the
joint bound of what ``estimate batch`` fits with the valves' dead time and supply drop, from
the same information matrix: at the batch estimate (``--at``) it equals the fit's sigmas
(the noise part and the total with the stated force_sigma_n);
a parameter the run does not inform is reported as such (never a NaN), a run informing
nothing is one line."""

import json
from pathlib import Path

from tests.support.cli import run as run_cli

ROOT = Path(__file__).resolve().parents[3]
EIGHT = ROOT / "vehicles" / "example-8-onoff.toml"
NAMES = "mass,izz,cx,cy,delay,drop"


def _files(tmp_path: Path) -> tuple[Path, Path]:
    """``(truth, model)`` vehicle files: the truth with a 30 ms delay and a 3 % drop and
    exact forces, the model the file as it is (force_sigma_n 0.005 N per valve)."""
    text = EIGHT.read_text()
    truth, model = tmp_path / "truth.toml", tmp_path / "model.toml"
    truth.write_text(text.replace("force_sigma_n = 0.005\n", "")
                     .replace("delay_s = 0.0", "delay_s = 0.03")
                     + "\n[supplies.main]\ndrop_per_valve = 0.03\n")
    model.write_text(text)
    return truth, model


def _sim(tpods_exe, tmp_path: Path, spec: str) -> tuple[Path, Path]:
    """``(run, model vehicle)`` of a 20 s simulated run of ``spec``."""
    truth, model = _files(tmp_path)
    out = tmp_path / "run"
    r = run_cli(tpods_exe, "sim", "--vehicle", str(truth), "--input", spec, "--mass", "23.09",
                "--izz", "0.31", "--duration", "20", "--seed", "4", "--out", str(out))
    assert r.returncode == 0, r.stderr
    return out, model


def test_the_bound_at_the_estimate_is_the_batch_fits_sigma(tpods_exe, tmp_path):
    run, model = _sim(tpods_exe, tmp_path, "pulse-groups")
    r = run_cli(tpods_exe, "estimate", "batch", str(run), "--vehicle", str(model), "--estimate",
                NAMES, "--json")
    assert r.returncode == 0, r.stderr
    est = json.loads(r.stdout)
    assert est["converged"] and est["estimated"] == NAMES.split(",")
    at = ",".join(f"{n}={est['params'][n]!r}" for n in est["estimated"])
    r = run_cli(tpods_exe, "estimate", "crlb", str(run), "--vehicle", str(model), "--estimate",
                NAMES, "--at", at, "--json")
    assert r.returncode == 0, r.stderr
    bound = json.loads(r.stdout)
    assert bound["estimated"] == NAMES.split(",") and not bound["not_informed"]
    assert set(bound["crlb_sigma"]) == set(NAMES.split(","))
    assert est["thrust_uncertainty"]["included"] and bound["thrust_uncertainty"]["included"]
    assert bound["thrust_uncertainty"]["terms"] == est["thrust_uncertainty"]["terms"]
    for n in est["estimated"]:  # noise part, and the total with the valves' force_sigma_n
        assert abs(bound["crlb_sigma"][n] / est["sigma_noise"][n] - 1) < 0.01, n
        assert abs(bound["crlb_sigma_total"][n] / est["sigma"][n] - 1) < 0.01, n
        assert est["sigma"][n] > 1.2 * est["sigma_noise"][n], n
        assert bound["at"][n] == est["params"][n]
    assert bound["crlb_mass_sigma_kg"] == bound["crlb_sigma"]["mass"]


def test_a_drop_the_run_does_not_inform_is_reported_not_bounded(tpods_exe, tmp_path):
    run, model = _sim(tpods_exe, tmp_path, "pulses")  # one valve open at a time
    r = run_cli(tpods_exe, "estimate", "crlb", str(run), "--vehicle", str(model), "--estimate",
                "mass,izz,delay,drop", "--json")
    assert r.returncode == 0, r.stderr
    assert "NaN" not in r.stdout and "Infinity" not in r.stdout
    bound = json.loads(r.stdout)
    assert bound["crlb_sigma"]["drop"] is None and "drop" not in bound["estimated"]
    assert "at the same time" in bound["not_informed"]["drop"]
    assert all(bound["crlb_sigma"][n] > 0 for n in ("mass", "izz", "delay"))
    warned = [ln for ln in r.stderr.splitlines() if "drop is not bounded" in ln]
    assert len(warned) == 1 and warned[0].startswith("tpods: warning: ")


def test_a_run_whose_valves_never_open_is_one_line(tpods_exe, tmp_path):
    _, model = _files(tmp_path)
    cmds = tmp_path / "zero.csv"
    cmds.write_text("t," + ",".join(f"d{i}" for i in range(1, 9)) + "\n"
                    + "0" + ",0" * 8 + "\n5" + ",0" * 8 + "\n")
    r = run_cli(tpods_exe, "sim", "--vehicle", str(model), "--input", str(cmds), "--mass", "23",
                "--izz", "0.3", "--duration", "5", "--out", str(tmp_path / "run"))
    assert r.returncode == 0, r.stderr
    r = run_cli(tpods_exe, "estimate", "crlb", str(tmp_path / "run"), "--vehicle", str(model),
                "--estimate", "mass,izz,delay", "--json")
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    assert lines[0].startswith("tpods: error: ") and "the valves never open" in lines[0]
    r = run_cli(tpods_exe, "estimate", "crlb", str(tmp_path / "run"), "--vehicle", str(model),
                "--at", "delay=0.01")
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "--at" in r.stderr, r.stderr
