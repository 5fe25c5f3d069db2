"""A load-cell log read in the wrong unit is named with the --force-unit that would fit: the
public HX711 logs (runs/fixtures/real/aevarofjord-thrusters, MIT; grams) read as N (a valve
of 45 N) or as kg (441 N). Read as mN the same log gives 45 mN, a force small thrusters do
give: not questioned, and this test does not claim it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from common.plausible_inputs import loadcell_force_warning
from tests.support.cli import run_in_process

HERE = Path(__file__).resolve().parents[2] / "runs" / "fixtures" / "real" / "aevarofjord-thrusters"
LOG = "MPC_Thruster(8)_20250707_221229.csv"


@pytest.mark.parametrize("unit, fix", [("N", "--force-unit g"), ("kg", "--force-unit g")])
def test_a_log_read_in_the_wrong_unit_is_named(tmp_path, unit, fix):
    sess = tmp_path / "s"
    r = run_in_process("bench", "import", str(HERE / LOG), "--out", str(sess), "--force-unit", unit)
    assert r.returncode == 0, r.stderr
    r = run_in_process("bench", "fit", str(sess), "--json")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    w = [x for x in doc["warnings"] if "outside 0.005-5 N" in x]
    assert w and fix in w[0], doc["warnings"]


def test_the_right_unit_is_not_questioned(tmp_path):
    sess = tmp_path / "s"
    assert run_in_process("bench", "import", str(HERE / LOG), "--out", str(sess)).returncode == 0
    r = run_in_process("bench", "fit", str(sess), "--json")
    assert r.returncode == 0, r.stderr
    assert not [x for x in json.loads(r.stdout)["warnings"] if "outside 0.005-5 N" in x]


def test_pure_rule():
    assert loadcell_force_warning(0.45, "g", "v") is None
    w = loadcell_force_warning(46.0 * 9.8, "N", "valve 1")  # grams read as newtons
    assert "--force-unit g: " in w
    assert loadcell_force_warning(float("nan"), "g", "v") is None
