"""Structure runs (issue 18) beyond the default batch fit: the filters' structure keys,
friction and tilt models on structures, degenerate runs refused naming what they cannot
determine."""

import json
from pathlib import Path

import pytest

from tests.support.cli import run_in_process
from tests.support.structures import TRUSS_TOML as TRUSS

FIXTURE = Path(__file__).resolve().parents[3] / "runs" / "fixtures" / "structure-run"


@pytest.mark.parametrize("extra", [(), ("--fixed", "cx=0.03")])
def test_ls_ekf_json_has_the_structure_keys(tpods_exe, extra):
    """--method ls-ekf gives com_x_m, com_y_m, izz_origin_kgm2 (+ sigmas) and structure like
    --method ls: the filter's final mean and covariance; sigma 0 for a fixed value."""
    r = run_in_process("estimate", "batch", str(FIXTURE), "--method", "ls-ekf", "--json", *extra)
    assert r.returncode == 0, r.stderr
    f = json.loads(r.stdout)
    assert f["structure"] == "truss" and not f["diverged"]
    p, s = f["params"], f["sigmas"]
    if extra:
        assert "cx" not in p and f["com_x_m"] == 0.03 and f["com_x_sigma_m"] == 0.0
    else:
        assert f["com_x_m"] == p["cx"] and f["com_x_sigma_m"] == s["cx"] > 0
        assert abs(f["com_x_m"] - 0.03) < 3.5 * s["cx"]
    assert f["com_y_m"] == p["cy"] and f["com_y_sigma_m"] == s["cy"] > 0
    m, izz, cx, cy = f["mass_kg"], f["izz_kgm2"], f["com_x_m"], f["com_y_m"]
    assert f["izz_origin_kgm2"] == pytest.approx(izz + m * (cx * cx + cy * cy), rel=1e-12)
    # Izz about the origin is no better known than Izz about the centre of mass and m c^2
    assert f["izz_sigma_kgm2"] * 0.5 < f["izz_origin_sigma_kgm2"] < 10 * f["izz_sigma_kgm2"]
    assert f["com_x_error_m"] == pytest.approx(cx - 0.03, abs=1e-15)
    text = run_in_process("estimate", "batch", str(FIXTURE), "--method", "ls-ekf", *extra)
    assert text.returncode == 0, text.stderr
    assert "centre of mass (+0.030" in text.stdout and "Izz about the tracked origin" in text.stdout


SYMMETRIC = """
name = "symmetric"
[[modules]]
name = "left"
position_m = [-0.25, 0.0]
[[modules]]
name = "right"
position_m = [0.25, 0.0]
"""
# both modules push alike: thrusters 2+3 push +x, 1+4 -x, 1+2 +y, 3+4 -y (docs/run-format.md);
# the two modules' moments about the tracked origin cancel: no torque in any row
PUSH = {"+x": [0, 50, 50, 0], "-x": [50, 0, 0, 50], "+y": [50, 50, 0, 0], "-y": [0, 0, 50, 50]}


def _pure_translation(folder: Path, dirs, body: str = "", closed: bool = False) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "s.toml").write_text(SYMMETRIC + body)
    rows = ["t," + ",".join(f"d{i}" for i in range(1, 9))]
    for k, d in enumerate(dirs * 4):
        duty = [0] * 8 if closed else PUSH[d] * 2
        rows.append(f"{2.0 * k:g}," + ",".join(map(str, duty)))
    rows.append(f"{2.0 * len(dirs) * 4:g}," + ",".join(["0"] * 8))
    (folder / "commands.csv").write_text("\n".join(rows) + "\n")
    return folder


def _sim(tpods_exe, folder: Path, seed: int = 1) -> str:
    r = run_in_process("sim", "--structure", str(folder / "s.toml"), "--input",
            str(folder / "commands.csv"), "--drop", "0.05", "--seed", str(seed), "--out",
            str(folder / "run"))
    assert r.returncode == 0, r.stderr
    return str(folder / "run")


def _one_line_error(r) -> str:
    assert r.returncode == 2 and "Traceback" not in r.stderr, (r.returncode, r.stderr)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("tpods: error: "), r.stderr
    return lines[0]


def test_a_structure_run_without_torque_is_refused_naming_izz_cx_cy(tpods_exe, tmp_path):
    """issue 18 done-when: pure translation (no torque about the tracked origin) with the
    centre of mass at the origin never turns the structure: Izz is undetermined, and with it
    cx, cy (only cx/Izz, cy/Izz are fixed); mass is determined and not named."""
    run_dir = _sim(tpods_exe, _pure_translation(tmp_path / "a", ["+x", "+y", "-x", "-y"]))
    line = _one_line_error(run_in_process("estimate", "batch", run_dir))
    assert "izz, cx, cy cannot be estimated" in line
    assert "no command produces a torque about the tracked origin" in line
    assert "mass" not in line.split("cannot be estimated")[0]
    assert "--fixed izz=" in line
    # the filters too (alone, the EKF reported Izz 14 +/- 0.005 kg m^2 here: its prior shrunk)
    for method in ("ekf", "ls-ekf"):
        assert "izz, cx, cy cannot be estimated" in _one_line_error(
            run_in_process("estimate", "batch", run_dir, "--method", method))
    # Izz known: the same run locates the centre of mass (at the origin, to microns)
    r = run_in_process("estimate", "batch", run_dir, "--fixed", "izz=0.03", "--json")
    assert r.returncode == 0, r.stderr
    est = json.loads(r.stdout)
    assert est["estimated"] == ["mass", "cx", "cy"] and est["converged"]
    for k in ("com_x", "com_y"):
        assert 0 < est[f"{k}_sigma_m"] < 1e-4 and abs(est[f"{k}_m"]) < 3.5 * est[f"{k}_sigma_m"]
    # pushing along x only, Izz known: nothing turns the structure about y's moment arm,
    # cx is not located (sigma beyond the structure's size) and is named alone
    run_x = _sim(tpods_exe, _pure_translation(tmp_path / "b", ["+x", "-x"]))
    line = _one_line_error(run_in_process("estimate", "batch", run_x, "--fixed", "izz=0.03"))
    assert "cx cannot be estimated" in line and "structure's size" in line


def test_the_same_commands_turn_a_structure_whose_centre_of_mass_is_off(tpods_exe, tmp_path):
    """No torque about the origin is not degenerate by itself: with the centre of mass 3 cm
    off it, the thrust's moment about the centre of mass turns the structure and every
    unknown is determined (not refused)."""
    body = "[body]\nmass_kg = 1.6\nizz_kgm2 = 0.03\ncom_m = [0.03, 0.01]\n"
    folder = _pure_translation(tmp_path, ["+x", "+y", "-x", "-y"], body)
    run_dir = _sim(tpods_exe, folder)
    (Path(run_dir) / "structure.toml").write_text(SYMMETRIC)  # the estimator is not told
    r = run_in_process("estimate", "batch", run_dir, "--json")
    assert r.returncode == 0, r.stderr
    est = json.loads(r.stdout)
    assert est["converged"] and est["izz_sigma_kgm2"] < 0.05 * est["izz_kgm2"]
    for key, sig, true in (("mass_kg", "mass_sigma_kg", 1.6), ("izz_kgm2", "izz_sigma_kgm2", 0.03),
                           ("com_x_m", "com_x_sigma_m", 0.03), ("com_y_m", "com_y_sigma_m", 0.01)):
        assert abs(est[key] - true) < 3.5 * est[sig], (key, est[key], est[sig])


def test_a_structure_run_with_every_valve_closed_is_refused(tpods_exe, tmp_path):
    run_dir = _sim(tpods_exe, _pure_translation(tmp_path, ["+x"], closed=True))
    line = _one_line_error(run_in_process("estimate", "batch", run_dir))
    assert "mass, izz, cx, cy cannot be estimated" in line and "no thrust" in line


FRICTION = {"ct": 0.2, "cr": 2e-3, "kb": 3e-3}


def _crlb_sigma(bound: dict, name: str) -> float:
    return bound.get({"mass": "crlb_mass_sigma_kg", "izz": "crlb_izz_sigma_kgm2"}.get(name, ""),
                     bound.get(f"crlb_{name}_sigma"))


@pytest.mark.parametrize("model, com, tilt, seed", [
    ("friction", (-0.02, 0.015), None, 5),
    ("friction+tilt", (0.03, -0.01), (1e-3, -5e-4), 3)])
def test_friction_models_on_a_structure_are_efficient(tpods_exe, tmp_path, model, com, tilt,
                                                      seed):
    """issue 18: --model friction|friction+tilt for structures: the model's parameters join
    mass, izz, cx, cy (friction and tilt act at the centre of mass); batch LS within 3.5
    sigma of the truth and sigma within 10 % of the CRLB of the same model (estimate crlb
    --model); ls-ekf carries them too."""
    (tmp_path / "truss.toml").write_text(TRUSS)  # no [body]: the estimator starts from the layout
    truth = {"mass": 1.6, "izz": 0.03, "cx": com[0], "cy": com[1], **FRICTION}
    opts = ["--friction", ",".join(str(FRICTION[k]) for k in ("ct", "cr", "kb"))]
    if tilt:
        truth.update(ax=tilt[0], ay=tilt[1])
        opts += ["--tilt", f"{tilt[0]},{tilt[1]}"]
    r = run_in_process("sim", "--structure", str(tmp_path / "truss.toml"), "--mass", "1.6",
            "--izz", "0.03", f"--com={com[0]},{com[1]}", *opts, "--duration", "60", "--drop",
            "0.05", "--seed", str(seed), "--out", str(tmp_path / "run"))
    assert r.returncode == 0, r.stderr
    run_dir = str(tmp_path / "run")
    r = run_in_process("estimate", "batch", run_dir, "--model", model, "--json")
    assert r.returncode == 0, r.stderr
    est = json.loads(r.stdout)
    assert est["converged"] and est["model"] == model
    assert est["estimated"] == ["mass", "izz", "cx", "cy", *(n for n in truth if n in
                                                             ("ct", "cr", "kb", "ax", "ay"))]
    r = run_in_process("estimate", "crlb", run_dir, "--model", model, "--json")
    assert r.returncode == 0, r.stderr
    bound = json.loads(r.stdout)
    assert bound["estimated"] == est["estimated"]
    for n in est["estimated"]:
        value, sigma = est["z0"][n], est["sigma"][n]
        assert abs(value - truth[n]) < 3.5 * sigma, (n, value, truth[n], sigma)
        assert sigma == pytest.approx(_crlb_sigma(bound, n), rel=0.10), n
    if tilt:
        r = run_in_process("estimate", "batch", run_dir, "--model", model, "--method", "ls-ekf",
                "--json")
        assert r.returncode == 0, r.stderr
        f = json.loads(r.stdout)
        assert not f["diverged"] and f["model"] == model and f["estimated"] == est["estimated"]
        for n in est["estimated"]:
            assert abs(f["params"][n] - truth[n]) < 3.5 * f["sigmas"][n], n
            # reuse filters the LS window's 20 s twice: a little below the batch sigma
            assert 0.7 < f["sigmas"][n] / est["sigma"][n] < 1.1, n
        assert f["com_x_m"] == f["params"]["cx"]
        # handoff uses every pose once: the filter is efficient too
        r = run_in_process("estimate", "batch", run_dir, "--model", model, "--method", "ls-ekf",
                "--ls-start", "handoff", "--json")
        assert r.returncode == 0, r.stderr
        h = json.loads(r.stdout)
        for n in est["estimated"]:
            assert abs(h["params"][n] - truth[n]) < 3.5 * h["sigmas"][n], n
            assert h["sigmas"][n] == pytest.approx(_crlb_sigma(bound, n), rel=0.10), n
        # plain ekf from the layout start: whatever its fate, a result and no traceback
        r = run_in_process("estimate", "batch", run_dir, "--model", model, "--method", "ekf")
        assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr


def test_model_auto_selects_a_structure_model_with_the_centre_of_mass(tpods_exe, tmp_path):
    """--model auto on a structure: ideal, friction and friction+tilt, each with cx, cy,
    fitted from the structure's start and chosen by likelihood-ratio tests: the frictionless
    fixture keeps ideal; a run with friction (no tilt) chooses friction."""
    r = run_in_process("estimate", "batch", str(FIXTURE), "--model", "auto", "--json")
    assert r.returncode == 0, r.stderr
    est = json.loads(r.stdout)
    assert est["model"] == "ideal" and est["estimated"] == ["mass", "izz", "cx", "cy"]
    assert est["model_selection"]["chosen"] == "ideal" and est["converged"]
    assert "with cx, cy in every model" in r.stderr
    (tmp_path / "truss.toml").write_text(TRUSS)
    r = run_in_process("sim", "--structure", str(tmp_path / "truss.toml"), "--mass", "1.6",
            "--izz", "0.03", "--com=-0.02,0.015", "--friction", "0.2,2e-3,3e-3", "--duration",
            "40", "--drop", "0.05", "--seed", "5", "--out", str(tmp_path / "run"))
    assert r.returncode == 0, r.stderr
    r = run_in_process("estimate", "batch", str(tmp_path / "run"), "--model", "auto", "--json")
    assert r.returncode == 0, r.stderr
    est = json.loads(r.stdout)
    assert est["model"] == "friction" and est["converged"]
    assert est["estimated"] == ["mass", "izz", "cx", "cy", "ct", "cr", "kb"]
    assert abs(est["com_x_m"] + 0.02) < 3.5 * est["com_x_sigma_m"]
    assert abs(est["z0"]["ct"] - 0.2) < 3.5 * est["sigma"]["ct"]
    line = _one_line_error(run_in_process("estimate", "batch", str(FIXTURE), "--model",
                               "friction", "--fixed", "ct=0.1"))
    assert "--model friction estimates ct; do not also fix it" in line
