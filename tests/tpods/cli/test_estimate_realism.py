"""CLI: --model for estimate batch (ls, ls-ekf) and crlb, --model auto, refusals, the report."""

import json

import pytest

from estimator.plant.sim import write_sim_run
from estimator.reports.realism import FRICTION, IZZ_KGM2, MASS_KG, TRUTH
from tests.support.cli import run_in_process


def _one_line_error(r):
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "error" in lines[0], r.stderr
    return lines[0]


def test_auto_picks_friction_and_says_why(tpods_exe, run_dirs):
    r = run_in_process("estimate", "batch", str(run_dirs["friction"]), "--model", "auto", "--json")
    assert r.returncode == 0, r.stderr
    obj = json.loads(r.stdout)
    assert obj["model"] == "friction"
    assert obj["estimated"] == ["mass", "izz", "ct", "cr", "kb"]
    sel = obj["model_selection"]
    assert sel["chosen"] == "friction" and "significantly better than ideal" in sel["reason"]
    assert set(sel["fits"]) == {"ideal", "friction", "friction+tilt"}
    assert "chosen: friction" in r.stderr  # the table goes to stderr with --json
    assert abs(obj["mass_kg"] - MASS_KG) < 3 * obj["mass_sigma_kg"]
    assert abs(obj["izz_kgm2"] - IZZ_KGM2) < 3 * obj["izz_sigma_kgm2"]


def test_model_friction_tilt_batch_and_crlb(tpods_exe, run_dirs, tmp_path):
    d = str(run_dirs["tilt"])
    r = run_in_process("estimate", "batch", d, "--model", "friction+tilt", "--json",
            "--out", str(tmp_path / "o"))
    assert r.returncode == 0, r.stderr
    obj = json.loads(r.stdout)
    assert obj["model"] == "friction+tilt" and obj["converged"]
    for k, v in TRUTH.items():
        assert abs(obj["z0"][k] - v) < 3.5 * obj["sigma"][k], k
    # the bound of this run under the extended model, reported beside the estimate
    assert abs(obj["mass_sigma_kg"] / obj["crlb_mass_sigma_kg"] - 1) < 0.2
    assert (tmp_path / "o" / "residuals.png").exists()
    c = run_in_process("estimate", "crlb", d, "--model", "friction+tilt", "--json")
    assert c.returncode == 0, c.stderr
    cb = json.loads(c.stdout)
    assert cb["model"] == "friction+tilt" and cb["estimated"][-1] == "ay"
    assert cb["crlb_mass_sigma_kg"] == pytest.approx(obj["crlb_mass_sigma_kg"], rel=1e-6)
    assert cb["crlb_ax_sigma"] > 0 and len(cb["crlb_correlation"]) == 7
    ideal = json.loads(run_in_process("estimate", "crlb", d, "--json").stdout)
    assert ideal["crlb_mass_sigma_kg"] < cb["crlb_mass_sigma_kg"]
    t = run_in_process("estimate", "crlb", d, "--model", "friction")
    assert t.returncode == 0 and "kb    sigma >=" in t.stdout


def test_ls_ekf_with_friction_model(tpods_exe, run_dirs):
    r = run_in_process("estimate", "batch", str(run_dirs["friction"]), "--method", "ls-ekf",
            "--model", "friction", "--ls-window", "10", "--ls-start", "handoff", "--json")
    assert r.returncode == 0, r.stderr
    obj = json.loads(r.stdout)
    assert obj["method"] == "ls-ekf" and obj["model"] == "friction"
    assert set(obj["params"]) == {"mass", "izz", "ct", "cr", "kb"}
    assert abs(obj["params"]["ct"] - FRICTION["ct"]) < 3 * obj["sigmas"]["ct"]
    assert "rmse_mass_kg" in obj and obj["ls"]["converged"]


def test_refusals(tpods_exe, run_dirs):
    d = str(run_dirs["none"])
    line = _one_line_error(run_in_process("estimate", "batch", d, "--model", "friction",
                               "--estimate", "mass,izz,ct"))
    assert "conflicts" in line
    line = _one_line_error(run_in_process("estimate", "batch", d, "--model", "friction",
                               "--fixed", "ct=0.1"))
    assert "estimates ct" in line
    _one_line_error(run_in_process("estimate", "batch", d, "--model", "viscous"))
    _one_line_error(run_in_process("estimate", "crlb", d, "--model", "auto"))
    _one_line_error(run_in_process("estimate", "batch", d, "--model", "auto",
                        "--select-alpha", "2"))


def test_report_realism_small(tpods_exe, tmp_path):
    out = tmp_path / "rep"
    r = run_in_process("report", "realism", "--out", str(out), "--runs", "3", "--seeds", "1",
            "--no-ekf")
    assert r.returncode == 0, r.stderr
    md = (out / "realism.md").read_text()
    for needle in ("ideal + hand-set friction", "friction+tilt (estimated)", "0.305",
                   "Identifiability", "average NEES", "chosen"):
        assert needle in md, needle
    data = json.loads((out / "realism.json").read_text())
    rows = data["comparison"]["B: friction + bias + 0.1 mrad tilt"]
    ideal, joint = rows[0], rows[3]
    assert ideal["mass_rmse_kg"] > 20 * joint["mass_rmse_kg"]
    assert data["selection"]["frictionless"]["chosen"] == ["ideal"]
    for f in ("residuals.png", "acf.png", "montecarlo.png"):
        assert (out / f).stat().st_size > 1000


@pytest.fixture(scope="module")
def run_dirs(tmp_path_factory):
    """Run folders: 'friction' (friction + yaw bias), 'tilt' (+ tilt), 'none' (frictionless)."""
    from estimator.reports.realism import simulate_run

    base = tmp_path_factory.mktemp("realism")
    out = {}
    for name, truth, seed in (("friction", FRICTION, 31), ("tilt", TRUTH, 32), ("none", {}, 33)):
        res, _, _ = simulate_run(truth, seed)
        out[name] = write_sim_run(res, base / name, "translate-rotate")
    return out
