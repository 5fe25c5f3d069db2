"""CLI of the batch estimator, the CRLB, design and the Table 3 report (through the installed script)."""

import json

import numpy as np
import pytest

from estimator.plant.inputs import phase_sine
from estimator.plant.model import PlantParams
from estimator.plant.sim import SimConfig, simulate, write_sim_run
from tests.support.cli import run_in_process
from tpods.cli import main


@pytest.fixture(scope="module")
def sim_run(tmp_path_factory):
    d = tmp_path_factory.mktemp("batchcli") / "run"
    cmd_t, duty = phase_sine(25.0, 50.0)
    res = simulate(cmd_t, duty, PlantParams(3.1, 6.5e-3), config=SimConfig(seed=9, drop=0.05))
    write_sim_run(res, d)
    return d


def _one_line_error(r):
    assert r.returncode != 0
    assert "Traceback" not in r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "error" in lines[0], r.stderr
    return lines[0]


def test_batch_json_is_one_object_with_the_keys(tpods_exe, sim_run, tmp_path):
    r = run_in_process("estimate", "batch", str(sim_run), "--method", "ls", "--json",
            "--out", str(tmp_path / "o"))
    assert r.returncode == 0, r.stderr
    obj = json.loads(r.stdout)  # exactly one JSON document
    for k in ("method", "mass_kg", "mass_sigma_kg", "izz_kgm2", "izz_sigma_kgm2", "converged",
              "iterations"):
        assert k in obj
    assert obj["method"] == "ls" and obj["converged"] is True
    assert abs(obj["mass_error_kg"]) < 3 * obj["mass_sigma_kg"]
    assert abs(obj["izz_error_kgm2"]) < 3 * obj["izz_sigma_kgm2"]
    assert abs(obj["mass_sigma_kg"] / obj["crlb_mass_sigma_kg"] - 1) < 0.2
    est = json.loads((tmp_path / "o" / "estimate.json").read_text())
    assert est["mass_kg"] == obj["mass_kg"]
    assert (tmp_path / "o" / "residuals.png").stat().st_size > 10_000
    res = np.loadtxt(tmp_path / "o" / "residuals.csv", delimiter=",", skiprows=1)
    assert res.shape[1] == 4 and res.shape[0] == est["n_poses"]


def test_batch_summary_window_initial_and_names(tpods_exe, sim_run):
    r = run_in_process("estimate", "batch", str(sim_run), "--window", "2:20", "--initial",
            "m=1.5,izz=0.01", "--estimate", "mass,izz,ct", "--fixed", "cr=0,kb=0")
    assert r.returncode == 0, r.stderr
    assert "converged" in r.stdout and "mass  =" in r.stdout and "ct    =" in r.stdout
    assert "t = 2.0" in r.stdout


def test_crlb_json_and_planned_sequence(tpods_exe, sim_run, tmp_path):
    r = run_in_process("estimate", "crlb", str(sim_run), "--json", "--out", str(tmp_path / "c"))
    assert r.returncode == 0, r.stderr
    obj = json.loads(r.stdout)
    assert obj["crlb_mass_sigma_kg"] > 0 and obj["crlb_izz_sigma_kgm2"] > 0
    assert obj["plant_source"] == "run truth" and obj["mass_kg"] == 3.1
    assert (tmp_path / "c" / "sensitivities.png").exists()
    # a planned sequence (commands only): poses at 120 Hz over the commanded span
    planned = tmp_path / "plan"
    planned.mkdir()
    (planned / "commands.csv").write_text((sim_run / "commands.csv").read_text())
    r2 = run_in_process("estimate", "crlb", str(planned), "--mass", "3.1", "--izz", "6.5e-3")
    assert r2.returncode == 0, r2.stderr
    assert "planned" in r2.stdout and "sigma >=" in r2.stdout


def test_design_writes_a_playable_commands_csv(tpods_exe, tmp_path):
    out = tmp_path / "d"
    r = run_in_process("design", "--duration", "15", "--cmd-rate", "20", "--pose-rate", "40",
            "--candidates", "6", "--refine", "1", "--refine-evals", "8", "--compare",
            "translate-rotate", "--out", str(out), "--json")
    assert r.returncode == 0, r.stderr
    obj = json.loads(r.stdout)
    assert obj["best"]["feasible"] is True
    assert obj["improvement_logdet"] == pytest.approx(obj["best"]["logdet_info"] - obj["paper"]["logdet_info"])
    assert obj["compared"][0]["label"] == "translate-rotate"
    # the written sequence is a valid commands.csv: simulate it and bound it
    sim = run_in_process("sim", "--input", str(out / "commands.csv"), "--duration", "15",
              "--out", str(tmp_path / "simd"))
    assert sim.returncode == 0, sim.stderr
    c = run_in_process("estimate", "crlb", str(out / "commands.csv"), "--pose-rate", "40",
            "--json")
    assert c.returncode == 0, c.stderr
    assert json.loads(c.stdout)["logdet_info"] == pytest.approx(obj["best"]["logdet_info"], rel=1e-6)


def test_report_table3_regenerates(tpods_exe, tmp_path):
    out = tmp_path / "t3"
    r = run_in_process("report", "table3", "--out", str(out), "--duration", "30")
    assert r.returncode == 0, r.stderr
    md = (out / "report.md").read_text()
    for row in ("| Initial |", "| True |", "| Estimated |", "| Absolute error |",
                "| Relative error |", "| CRLB sigma at the truth |", "| Paper: estimated |",
                "Why the orbit follower leaves Izz poorly observable"):
        assert row in md
    data = json.loads((out / "table3.json").read_text())
    orbit, sine = data["cases"]["orbit"], data["cases"]["sine"]
    # the orbit follower bounds Izz far worse than the phase-shifted sine
    assert orbit["crlb_izz_sigma_kgm2"] > 50 * sine["crlb_izz_sigma_kgm2"]
    assert orbit["summary"]["rms_dyaw_dlnizz_rad"] < 0.01 < sine["summary"]["rms_dyaw_dlnizz_rad"]
    for case in (orbit, sine):
        e = case["estimate"]
        assert e["converged"]
        assert abs(e["mass_kg"] - 2.268) < 3 * e["mass_sigma_kg"]
        assert abs(e["izz_kgm2"] - 3.78e-3) < 3 * e["izz_sigma_kgm2"]
    for f in ("fig5_residuals_orbit.png", "fig5_residuals_sine.png",
              "fig6_sensitivities_orbit.png", "fig6_sensitivities_sine.png"):
        assert (out / f).stat().st_size > 10_000
    assert (out / "runs" / "sine" / "poses.csv").exists()


@pytest.mark.parametrize("args,needle", [
    (["estimate", "batch", "{missing}"], "not found"),
    (["estimate", "batch", "{run}", "--window", "50:60"], "fewer than 2 poses"),
    (["estimate", "batch", "{run}", "--window", "abc"], "window"),
    (["estimate", "batch", "{run}", "--initial", "m=-1"], "must be positive"),
    (["estimate", "batch", "{run}", "--initial", "volume=3"], "unknown name"),
    (["estimate", "batch", "{run}", "--estimate", "mass,foo"], "expected distinct names"),
    (["estimate", "batch", "{run}", "--estimate", "izz"], "neither estimated nor given"),
    (["estimate", "batch", "{run}", "--thrust-table", "{missing}"], "not found"),
    (["estimate", "batch", "{bad}"], "not a finite number"),
    (["estimate", "batch", "{badduty}"], "outside the thrust table's valid range"),
    (["estimate", "crlb", "{missing}"], "neither a run folder"),
    (["design", "--omega-range", "3,1", "--out", "{tmp}"], "--omega-range"),
    (["design", "--table-size", "0.1,0.1", "--margin", "0.1", "--out", "{tmp}"], "--table-size"),
])
def test_refusals_are_one_line(sim_run, tmp_path, capsys, args, needle):
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "commands.csv").write_text((sim_run / "commands.csv").read_text())
    lines = (sim_run / "poses.csv").read_text().splitlines()
    lines[5] = "0.04,nan,0,0"
    (bad / "poses.csv").write_text("\n".join(lines) + "\n")
    badduty = tmp_path / "badduty"
    badduty.mkdir()
    cl = (sim_run / "commands.csv").read_text().splitlines()
    cl[3] = cl[3].split(",")[0] + ",5,50,50,50"  # open valve below the 10 % threshold
    (badduty / "commands.csv").write_text("\n".join(cl) + "\n")
    (badduty / "poses.csv").write_text((sim_run / "poses.csv").read_text())
    subs = {"{missing}": str(tmp_path / "nope"), "{run}": str(sim_run), "{bad}": str(bad),
            "{badduty}": str(badduty), "{tmp}": str(tmp_path / "o")}
    # in-process (the same main() the script runs; saves the interpreter start-up per case)
    try:
        code = main([subs.get(a, a) for a in args])
    except SystemExit as exc:  # argparse errors
        code = exc.code
    err = capsys.readouterr().err
    assert code != 0
    assert "Traceback" not in err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and "error" in lines[0], err
    assert needle in lines[0], lines[0]


def test_filter_methods_are_delegated(tpods_exe, sim_run):
    # ekf / ls-ekf belong to the filter module: whatever it answers, never a traceback
    r = run_in_process("estimate", "batch", str(sim_run), "--method", "ekf", "--json")
    assert "Traceback" not in r.stderr
    if r.returncode == 0:
        obj = json.loads(r.stdout)
        assert obj["method"] == "ekf"


def test_poses_in_millimetres_warn_on_stderr_naming_the_likely_cause(tpods_exe, tmp_path):
    d = tmp_path / "mm"
    assert run_in_process("sim", "--duration", "20", "--noise-pos", "0.01", "--seed", "3",
               "--out", str(d)).returncode == 0
    poses = (d / "poses.csv").read_text().splitlines()
    rows = [poses[0]] + [",".join([t, str(float(x) * 1e3), str(float(y) * 1e3), psi])
                         for t, x, y, psi in (ln.split(",") for ln in poses[1:])]
    (d / "poses.csv").write_text("\n".join(rows) + "\n")
    r = run_in_process("estimate", "batch", str(d))
    warn = [ln for ln in r.stderr.splitlines() if ln.startswith("tpods: warning:")]
    assert any("millimetres" in w and "--sigma-pos" in w for w in warn), r.stderr
    assert "Traceback" not in r.stderr and "warning" not in r.stdout
