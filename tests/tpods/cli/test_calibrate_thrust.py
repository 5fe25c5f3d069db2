"""`tpods calibrate thrust` end to end (in process): a simulated run of a known body with one
weak nozzle gives a calibrated table that `tpods estimate batch` reads (its total sigma
carrying the calibration); existing outputs need --force; runs that cannot separate the
factors are refused in one line."""

from __future__ import annotations

import json

import numpy as np
import pytest

from common.thrust_table import ThrustTable
from estimator.batch.thrust_calibration.calibrate import with_factors
from estimator.plant.inputs import phase_sine, translate_rotate
from estimator.plant.model import PlantParams
from estimator.plant.sim import SimConfig, simulate, write_sim_run
from tpods.cli import main

WEAK = (1.0, 0.96, 1.0, 1.0)


def _run(path, inputs, mass, izz, seed=1):
    cmd_t, duty = inputs
    truth = with_factors(ThrustTable.default(), ("efficiency.1", "efficiency.2", "efficiency.3",
                                                 "efficiency.4"), WEAK)
    res = simulate(cmd_t, duty, PlantParams(mass, izz), thrust_n=truth.thrust_n(duty),
                   config=SimConfig(seed=seed))
    return write_sim_run(res, path)


def _rc(argv, capsys):
    try:
        rc = main(argv)
    except SystemExit as exc:
        rc = exc.code
    out = capsys.readouterr()
    return rc, out.out, [ln for ln in out.err.splitlines() if ln.strip()]


def test_calibrate_then_estimate(tmp_path, capsys):
    known = _run(tmp_path / "known", translate_rotate(28.0), 0.72, 0.0062)
    out = tmp_path / "cal.toml"
    argv = ["calibrate", "thrust", str(known), "--mass", "0.72", "--mass-sigma", "0.00144",
            "--izz", "0.0062", "--izz-sigma", "6.2e-5", "--thrust-table", "table2",
            "--out", str(out)]
    rc, text, err = _rc(argv, capsys)
    assert rc == 0, err
    assert "efficiency.2" in text and "known Izz uncertainty" in text and f"wrote {out}" in text
    table = ThrustTable.load(out)
    eff = table.calibration.efficiency
    sig = np.sqrt(np.diag(table.calibration.covariance))
    assert np.all(np.abs(np.array(eff) - WEAK) < 3 * sig)
    assert table.calibration.info["known"]["izz_kgm2"] == 0.0062
    assert table.coefficients == ThrustTable.default().coefficients
    # an existing table is refused without --force, replaced with it
    rc, _, err = _rc(argv, capsys)
    assert rc == 2 and len(err) == 1 and "already exists" in err[0] and "--force" in err[0]
    rc, text, err = _rc([*argv, "--force", "--json", "--per", "nozzles"], capsys)
    assert rc == 0, err
    d = json.loads(text)
    assert list(d["factors"]) == ["nozzle_scale.2"] and d["out"] == str(out)
    assert d["factors"]["nozzle_scale.2"]["limited_by"]
    assert ThrustTable.load(out).calibration.parameters == ("nozzle_scale.2",)
    # the unknown body with the calibrated (per-thruster) table: the total sigma covers
    rc, _, err = _rc([*argv, "--force"], capsys)
    assert rc == 0
    unknown = _run(tmp_path / "unknown", translate_rotate(28.0), 1.6, 0.0135, seed=2)
    rc, text, err = _rc(["estimate", "batch", str(unknown), "--thrust-table", str(out), "--json"],
                        capsys)
    assert rc == 0, err
    est = json.loads(text)
    assert est["thrust_uncertainty"]["included"]
    assert est["mass_sigma_thrust_kg"] > 0 and est["izz_sigma_thrust_kgm2"] > 0
    assert abs(est["mass_kg"] - 1.6) < 3 * est["mass_sigma_kg"]
    assert abs(est["izz_kgm2"] - 0.0135) < 3 * est["izz_sigma_kgm2"]


def test_output_folder_holds_table_and_json(tmp_path, capsys):
    known = _run(tmp_path / "known", translate_rotate(14.0), 0.72, 0.0062)
    rc, text, err = _rc(["calibrate", "thrust", str(known), "--mass", "0.72", "--izz", "0.0062",
                         "--thrust-table", "table2", "--out", str(tmp_path / "cal")], capsys)
    assert rc == 0, err
    assert (tmp_path / "cal" / "thrust_table.toml").is_file()
    d = json.loads((tmp_path / "cal" / "calibration.json").read_text())
    assert d["per"] == "thruster" and len(d["factors"]) == 4
    assert any("--mass-sigma" in ln for ln in err)  # the known values' sigma was not given


@pytest.mark.parametrize("case,msg", [
    ("sine-both", "nozzle_scale.4 with the common level of the efficiencies"),
    ("closed-4", "thruster 4 is never opened"),
    ("input-table", "would replace the input"),
])
def test_refusals_are_one_line(tmp_path, capsys, case, msg):
    if case == "sine-both":
        run = _run(tmp_path / "r", phase_sine(14.0), 0.72, 0.0062)
    else:
        cmd_t, duty = translate_rotate(14.0)
        duty = duty.copy()
        if case == "closed-4":
            duty[:, 3] = 0.0
        run = _run(tmp_path / "r", (cmd_t, duty), 0.72, 0.0062)
    table = tmp_path / "t.toml"
    ThrustTable.default().save(table)
    out = table if case == "input-table" else tmp_path / "new.toml"
    rc, _, err = _rc(["calibrate", "thrust", str(run), "--mass", "0.72", "--izz", "0.0062",
                      "--thrust-table", str(table), "--per", "both" if case == "sine-both"
                      else "thruster", "--out", str(out), "--force"], capsys)
    assert rc == 2 and len(err) == 1 and err[0].startswith("tpods: error: ") and msg in err[0], err
    assert not (tmp_path / "new.toml").exists()


def test_design_for_thrust_calibration(tmp_path, capsys):
    out = tmp_path / "des"
    argv = ["design", "--for", "thrust-calibration", "--duration", "20", "--candidates", "6",
            "--refine", "0", "--out", str(out), "--json"]
    rc, text, err = _rc(argv, capsys)
    assert rc == 0, err
    d = json.loads(text)
    assert d["for"] == "thrust-calibration" and d["best"]["feasible"]
    assert len(d["best"]["nozzle_counts_s"]) >= 2
    sine = next(e for e in d["compared"] if e["label"] == "phase-sine")
    assert not sine["feasible"] and "confounded" in sine["reason"]
    cmd = np.loadtxt(out / "commands.csv", delimiter=",", skiprows=1)
    open_ = cmd[:, 1:][cmd[:, 1:] > 0]
    assert np.all((open_ >= 10) & (open_ <= 90))
    rc, _, err = _rc(argv, capsys)  # an existing design needs --force
    assert rc == 2 and len(err) == 1 and "--force" in err[0]
