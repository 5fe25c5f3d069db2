"""Issue 16: a mass or Izz implausible for an air-table body warns, naming the thrust
table's unit (a gf table labelled N gave a mass error of 4e13 % without a word)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from estimator.batch.least_squares import body_warnings
from tests.support.cli import run_in_process

ROOT = Path(__file__).resolve().parents[3]


@pytest.mark.parametrize("mass,izz", [(2.268, 3.78e-3), (0.72, 1.2e-3), (0.06, 1e-5), (150.0, 20.0)])
def test_plausible_bodies_are_quiet(mass, izz):
    assert body_warnings(mass, izz) == []


@pytest.mark.parametrize("mass,izz,needle", [
    (231.0, 0.38, "mass 231 kg is outside 0.05-200 kg"),            # gf read as N: 102x
    (0.0222, 3.7e-5, "mass 0.0222 kg is outside 0.05-200 kg"),      # N read as gf
    (2.268, 1e-8, "radius of gyration of 6.64e-05 m, outside 1 cm-2 m"),
    (2.268, 50.0, "radius of gyration of 4.7 m"),
    (float("nan"), 1e-3, "mass nan kg"),
    (2.0, -1e-3, "Izz -0.001 kg m^2 is not positive"),
])
def test_implausible_bodies_warn_once_naming_the_unit(mass, izz, needle):
    w = body_warnings(mass, izz, "t.toml", "N")
    assert len(w) == 1 and needle in w[0] and 't.toml says unit = "N"' in w[0] and "102x" in w[0], w


def test_cli_gf_table_labelled_newtons(tpods_exe, tmp_path):
    assert run_in_process("sim", "--duration", "6", "--out", str(tmp_path / "r")).returncode == 0
    table = tmp_path / "t.toml"
    table.write_text((ROOT / "common" / "data" / "table2_60psi.toml").read_text()
                     .replace('unit = "gf"', 'unit = "N"'))
    r = run_in_process("estimate", "batch", str(tmp_path / "r"), "--thrust-table", str(table), "--json")
    assert r.returncode == 0, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if "implausible for an air-table body" in ln]
    assert len(lines) == 1 and f'{table} says unit = "N"' in lines[0], r.stderr
    assert lines[0].startswith("tpods: warning: ")
    assert any("implausible" in w for w in json.loads(r.stdout)["warnings"])
    ok = run_in_process("estimate", "batch", str(tmp_path / "r"))
    assert ok.returncode == 0 and "implausible" not in ok.stderr, ok.stderr


def test_a_radius_of_gyration_below_a_lead_sphere_of_that_mass_warns():
    """The fit of a 6 s run with a gf table labelled N: 33 kg with the 2.3 kg module's Izz."""
    w = body_warnings(33.3, 5.17e-3)
    assert len(w) == 1 and "radius of gyration of 1.25 cm, less than any body of 33.3 kg can have" in w[0]
    assert body_warnings(2.268, 3.78e-3) == []  # the paper's module: 4.1 cm, a lead sphere 2.3 cm
