"""`tpods calibrate thrust` without --izz (issue 24, item 4): Izz estimated with the factors,
--per common and --per thruster in --json (today's `factors` object plus izz_kgm2 and
izz_sigma_kgm2), a run that does not inform Izz refused in one line, a dead thruster named
on stderr and in the JSON's warnings."""

from __future__ import annotations

import json

import numpy as np
import pytest

from common.thrust_table import ThrustTable
from estimator.plant.inputs import translate_rotate
from estimator.plant.model import PlantParams
from estimator.plant.sim import SimConfig, simulate, write_sim_run
from tests.support.cli import main_rc


def _run(path, gains=(1.0, 0.96, 1.0, 1.0), keep_s=None, seed=1):
    cmd_t, duty = translate_rotate(28.0)
    if keep_s is not None:
        cmd_t, duty = cmd_t[cmd_t <= keep_s], duty[cmd_t <= keep_s]
    res = simulate(cmd_t, duty, PlantParams(0.72, 0.0062),
                   thrust_n=ThrustTable.default().thrust_n(duty) * np.asarray(gains),
                   config=SimConfig(seed=seed))
    return write_sim_run(res, path)


_rc = main_rc


@pytest.mark.parametrize("per", ["thruster", "common"])
def test_izz_estimated_with_the_factors(tmp_path, capsys, per):
    run = _run(tmp_path / "r")
    out = tmp_path / "cal.toml"
    rc, text, err = _rc(["calibrate", "thrust", str(run), "--mass", "0.72", "--mass-sigma",
                         "0.00144", "--thrust-table", "table2", "--per", per, "--out", str(out),
                         "--json"], capsys)
    assert rc == 0, err
    d = json.loads(text)
    names = [f"efficiency.{i}" for i in range(1, 5)] if per == "thruster" else ["scale"]
    assert list(d["factors"]) == names
    assert all({"value", "sigma"} <= set(f) for f in d["factors"].values())
    assert d["izz_sigma_kgm2"] > 0 and set(d["izz_correlation"]) == set(names)
    if per == "thruster":  # the model fits: Izz within 3 sigma of the truth
        assert abs(d["izz_kgm2"] - 0.0062) < 3 * d["izz_sigma_kgm2"]
        assert abs(d["factors"]["efficiency.2"]["value"] - 0.96) < 3 * d["factors"]["efficiency.2"]["sigma"]
    cal = ThrustTable.load(out).calibration
    assert cal.parameters == tuple(f"efficiency.{i}" for i in range(1, 5))
    assert cal.info["known"]["izz_estimated_kgm2"] == d["izz_kgm2"]
    # the text output names the estimated Izz
    rc, text, err = _rc(["calibrate", "thrust", str(run), "--mass", "0.72", "--mass-sigma",
                         "0.00144", "--thrust-table", "table2", "--per", per, "--out", str(out),
                         "--force"], capsys)
    assert rc == 0 and "Izz estimated:" in text, err


@pytest.mark.parametrize("case,msg", [
    ("translation", "Izz is not identifiable from this run: it never turns the body"),
    ("izz-sigma", "--izz-sigma is the uncertainty of a known --izz"),
])
def test_refusals_are_one_line(tmp_path, capsys, case, msg):
    run = _run(tmp_path / "r", keep_s=7.0 if case == "translation" else None)
    extra = ["--izz-sigma", "1e-4"] if case == "izz-sigma" else []
    rc, _, err = _rc(["calibrate", "thrust", str(run), "--mass", "0.72", "--thrust-table",
                      "table2", "--per", "common", "--out", str(tmp_path / "n.toml"), *extra],
                     capsys)
    assert rc == 2 and len(err) == 1 and err[0].startswith("tpods: error: ") and msg in err[0], err
    assert not (tmp_path / "n.toml").exists()


def test_dead_thruster_named_on_stderr_and_in_json(tmp_path, capsys):
    run = _run(tmp_path / "r", gains=(1.0, 1.0, 0.0, 1.0))
    rc, text, err = _rc(["calibrate", "thrust", str(run), "--mass", "0.72", "--mass-sigma",
                         "0.00144", "--thrust-table", "table2", "--out", str(tmp_path / "n.toml"),
                         "--json"], capsys)
    d = json.loads(text)
    dead = [w for w in d["warnings"] if "Dead or blocked" in w]
    assert len(dead) == 1 and dead[0].startswith("thruster 3 (column d3)")
    assert any(ln.startswith("tpods: warning: thruster 3 (column d3)") for ln in err)
    if d["factors"]["efficiency.3"]["value"] <= 0:  # a table cannot hold it: refused, said why
        assert rc == 2 and err[-1].startswith("tpods: error: ") and d["out"] is None
    else:
        assert rc == 0 and ThrustTable.load(tmp_path / "n.toml").calibration.efficiency[2] > 0
