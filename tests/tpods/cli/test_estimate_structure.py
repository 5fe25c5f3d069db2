"""CLI of structure runs (issue 18): tpods sim --structure, estimate batch|crlb."""

import json

import pytest

from tests.support.cli import run_in_process
from tests.support.structures import TRUSS_TOML as STRUCTURE

# the simulation's truth as options: [body] values would be known values (fixed) to tpods
# estimate, not the truth the estimator is to find (tests/tpods/cli/test_structure_priors.py)
TRUTH = ("--mass", "1.6", "--izz", "0.03", "--com", "0.03,0")


@pytest.fixture(scope="module")
def structure_run(tpods_exe, tmp_path_factory):
    d = tmp_path_factory.mktemp("structure")
    (d / "truss.toml").write_text(STRUCTURE)
    r = run_in_process("sim", "--structure", str(d / "truss.toml"), *TRUTH, "--duration", "60",
            "--pose-rate", "120", "--drop", "0.05", "--seed", "1", "--out", str(d / "run"))
    assert r.returncode == 0, r.stderr
    return d


def _one_line_error(r):
    assert r.returncode == 2 and "Traceback" not in r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("tpods: error: "), r.stderr
    return lines[0]


def test_sim_writes_a_structure_run(structure_run):
    run_dir = structure_run / "run"
    assert (run_dir / "structure.toml").is_file()
    assert (run_dir / "commands.csv").read_text().splitlines()[0] == "t,d1,d2,d3,d4,d5,d6,d7,d8"
    truth = json.loads((run_dir / "run.json").read_text())["truth"]
    assert (truth["mass_kg"], truth["izz_kgm2"], truth["cx"], truth["cy"]) == (1.6, 0.03, 0.03, 0.0)


def test_batch_estimates_mass_izz_and_centre_of_mass_efficiently(tpods_exe, structure_run):
    run_dir = str(structure_run / "run")
    r = run_in_process("estimate", "batch", run_dir, "--json")
    assert r.returncode == 0, r.stderr
    est = json.loads(r.stdout)
    assert est["converged"] is True and est["estimated"] == ["mass", "izz", "cx", "cy"]
    c = run_in_process("estimate", "crlb", run_dir, "--json")
    assert c.returncode == 0, c.stderr
    bound = json.loads(c.stdout)
    assert bound["estimated"] == ["mass", "izz", "cx", "cy"]
    rows = [("mass", est["mass_kg"], est["mass_sigma_kg"], 1.6, bound["crlb_mass_sigma_kg"]),
            ("izz", est["izz_kgm2"], est["izz_sigma_kgm2"], 0.03, bound["crlb_izz_sigma_kgm2"]),
            ("cx", est["com_x_m"], est["com_x_sigma_m"], 0.03, bound["crlb_cx_sigma"]),
            ("cy", est["com_y_m"], est["com_y_sigma_m"], 0.0, bound["crlb_cy_sigma"])]
    for name, value, sigma, truth, crlb in rows:
        assert abs(value - truth) < 3.5 * sigma, (name, value, truth, sigma)
        assert sigma == pytest.approx(crlb, rel=0.10), (name, sigma, crlb)
    m, izz, cx, cy = est["mass_kg"], est["izz_kgm2"], est["com_x_m"], est["com_y_m"]
    assert est["izz_origin_kgm2"] == pytest.approx(izz + m * (cx * cx + cy * cy), rel=1e-12)
    assert 0 < est["izz_origin_sigma_kgm2"] < 10 * est["izz_sigma_kgm2"]
    assert est["com_x_error_m"] == pytest.approx(cx - 0.03)


def test_structure_refusals_are_one_line(tpods_exe, structure_run, tmp_path):
    run_dir = str(structure_run / "run")
    line = _one_line_error(run_in_process("estimate", "batch", run_dir, "--model", "friction",
                               "--fixed", "ct=0.1"))
    assert "--model friction estimates ct; do not also fix it" in line
    bad = tmp_path / "bad.toml"
    bad.write_text(STRUCTURE.replace("yaw_deg = 90", "yaw = 90"))
    line = _one_line_error(run_in_process("estimate", "batch", run_dir, "--structure", str(bad)))
    assert str(bad) in line and "did you mean 'yaw_deg'" in line
    three = tmp_path / "three.toml"
    three.write_text(STRUCTURE + '[[modules]]\nname = "m3"\nposition_m = [0, 0.3]\n')
    line = _one_line_error(run_in_process("estimate", "crlb", run_dir, "--structure", str(three)))
    assert "missing column(s) d9, d10, d11, d12" in line
    line = _one_line_error(run_in_process("sim", "--structure", str(bad), "--out", str(tmp_path / "o")))
    assert "did you mean 'yaw_deg'" in line


@pytest.mark.parametrize("seed", [2, 3])
def test_a_structure_without_body_values_starts_from_its_geometry(tpods_exe, structure_run,
                                                                   tmp_path, seed):
    """Seed 2 diverged from the paper's single-module start (1 kg, 5e-3 kg m^2 against a
    1.6 kg, 0.03 kg m^2 truss); the start now comes from the modules' layout (here 3x the
    mass and 6x the Izz: no [body] values are given to the estimator)."""
    bare = tmp_path / "bare.toml"
    bare.write_text(STRUCTURE)
    r = run_in_process("sim", "--structure", str(structure_run / "truss.toml"), *TRUTH, "--duration",
            "60", "--drop", "0.05", "--seed", str(seed), "--out", str(tmp_path / "run"))
    assert r.returncode == 0, r.stderr
    r = run_in_process("estimate", "batch", str(tmp_path / "run"), "--structure", str(bare),
            "--json")
    assert r.returncode == 0, r.stderr
    est = json.loads(r.stdout)
    assert est["converged"] and "structure's geometry" in est["start"]
    for key, sig_key, true in (("mass_kg", "mass_sigma_kg", 1.6),
                               ("izz_kgm2", "izz_sigma_kgm2", 0.03),
                               ("com_x_m", "com_x_sigma_m", 0.03), ("com_y_m", "com_y_sigma_m", 0.0)):
        assert abs(est[key] - true) < 3.5 * est[sig_key], (key, est[key], est[sig_key])


PARTS = """
about = "com"
[[part]]
name = "module tpods1"
mass_kg = 0.72
mass_sigma_kg = 0.0015
izz_kgm2 = 1.2e-3
izz_sigma_kgm2 = 3e-5
position_m = [-0.2, 0.0]
position_sigma_m = 0.002
[[part]]
name = "module tpods2"
mass_kg = 0.72
mass_sigma_kg = 0.0015
izz_kgm2 = 1.2e-3
izz_sigma_kgm2 = 3e-5
position_m = [0.2, 0.05]
position_sigma_m = 0.002
[[part]]
name = "truss bar"
mass_kg = 0.30
mass_sigma_kg = 0.001
shape = "rod"
length_m = 0.5
position_m = [0.05, 0.0]
position_sigma_m = 0.002
"""


def test_parts_ground_truth_compares_with_the_estimate_in_one_command(tpods_exe, tmp_path):
    """issue 18: `calibrate combine PARTS --compare ESTIMATE.json` puts the parallel-axis
    ground truth beside a structure estimate in the same frame and units."""
    (tmp_path / "parts.toml").write_text(PARTS)
    r = run_in_process("calibrate", "combine", str(tmp_path / "parts.toml"), "--json")
    assert r.returncode == 0, r.stderr
    gt = json.loads(r.stdout)
    assert gt["com_sigma_m"][0] > 0
    # the parts' values are the simulation's truth (options), not [body] values (known)
    truth = ("--mass", repr(gt["mass_kg"]), "--izz", repr(gt["izz_com_kgm2"]),
             f"--com={gt['com_m'][0]!r},{gt['com_m'][1]!r}")
    (tmp_path / "truss.toml").write_text(STRUCTURE)
    r = run_in_process("sim", "--structure", str(tmp_path / "truss.toml"), *truth, "--duration",
            "60", "--seed", "4", "--out", str(tmp_path / "run"))
    assert r.returncode == 0, r.stderr
    r = run_in_process("estimate", "batch", str(tmp_path / "run"), "--out",
            str(tmp_path / "est.json"))
    assert r.returncode == 0, r.stderr
    r = run_in_process("calibrate", "combine", str(tmp_path / "parts.toml"), "--compare",
            str(tmp_path / "est.json"), "--json")
    assert r.returncode == 0, r.stderr
    rows = {row["quantity"]: row for row in json.loads(r.stdout)["comparison"]}
    assert set(rows) == {"mass", "Izz (centre of mass)", "centre of mass x", "centre of mass y"}
    assert all(abs(row["difference_sigmas"]) < 3 for row in rows.values()), rows
    text = run_in_process("calibrate", "combine", str(tmp_path / "parts.toml"), "--compare",
               str(tmp_path / "est.json")).stdout
    assert "compared with" in text and "centre of mass x" in text
    bad = run_in_process("calibrate", "combine", str(tmp_path / "parts.toml"), "--compare",
              str(tmp_path / "missing.json"))
    assert bad.returncode == 2 and "--compare" in bad.stderr and "Traceback" not in bad.stderr


def test_design_for_a_structure_drives_every_module(tpods_exe, tmp_path):
    """issue 18: `tpods design --structure F`: D-optimal duties for all modules on (m, Izz,
    cx, cy), never worse than the hand-made phase-shifted sine over every channel."""
    (tmp_path / "bare.toml").write_text(STRUCTURE)
    r = run_in_process("design", "--structure", str(tmp_path / "bare.toml"), "--duration", "20",
            "--candidates", "6", "--refine", "1", "--refine-evals", "8", "--out",
            str(tmp_path / "design"), "--json")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["best"]["logdet_info"] >= out["paper"]["logdet_info"]
    assert len(out["best"]["phases_rad"]) == 8 and out["best"]["crlb_com_x_sigma_m"] > 0
    header = (tmp_path / "design" / "commands.csv").read_text().splitlines()[0]
    assert header == "t,d1,d2,d3,d4,d5,d6,d7,d8"
    assert (tmp_path / "design" / "structure.toml").is_file()
    # the design plays: a simulated run of it is a structure run the estimator reads
    r = run_in_process("sim", "--structure", str(tmp_path / "bare.toml"), "--input",
            str(tmp_path / "design" / "commands.csv"), "--out", str(tmp_path / "run"))
    assert r.returncode == 0, r.stderr


def test_ls_ekf_on_a_structure_carries_the_centre_of_mass(tpods_exe, structure_run, tmp_path):
    """issue 18: the extended filter estimates cx, cy too (the pose update sees the tracked
    frame off the centre of mass); ls-ekf from the geometric start ends within 3.5 sigma,
    its sigma near batch LS's (reuse counts the LS window twice: a little smaller)."""
    bare = tmp_path / "bare.toml"
    bare.write_text(STRUCTURE)
    run_dir = str(structure_run / "run")
    r = run_in_process("estimate", "batch", run_dir, "--structure", str(bare), "--json")
    ls = json.loads(r.stdout)
    r = run_in_process("estimate", "batch", run_dir, "--structure", str(bare), "--method",
            "ls-ekf", "--json")
    assert r.returncode == 0, r.stderr
    f = json.loads(r.stdout)
    assert not f["diverged"]
    for name, true, key in (("mass", 1.6, "mass"), ("izz", 0.03, "izz"), ("cx", 0.03, "cx"),
                            ("cy", 0.0, "cy")):
        assert abs(f["params"][name] - true) < 3.5 * f["sigmas"][name], name
        assert 0.7 < f["sigmas"][name] / ls["sigma"][key] < 1.3, name


def test_design_leaves_out_what_the_structure_gives_as_known(tpods_exe, tmp_path):
    """[body] com_m known (no sigma): the estimators fix cx, cy, so the D-optimal criterion
    is on mass and Izz only; everything known: nothing to design for, one line."""
    known = tmp_path / "known.toml"
    known.write_text(STRUCTURE + "[body]\ncom_m = [0.03, 0.0]\n")
    r = run_in_process("design", "--structure", str(known), "--duration", "20", "--candidates", "8",
            "--refine", "1", "--refine-evals", "2", "--out", str(tmp_path / "d"), "--json")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["criterion_parameters"] == ["mass", "izz"]
    full = tmp_path / "full.toml"
    full.write_text(STRUCTURE + "[body]\nmass_kg = 1.6\nizz_kgm2 = 0.03\ncom_m = [0.03, 0.0]\n")
    line = _one_line_error(run_in_process("design", "--structure", str(full), "--duration", "20",
                               "--out", str(tmp_path / "e")))
    assert "nothing left to design for" in line
