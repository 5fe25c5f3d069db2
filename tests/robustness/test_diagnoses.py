"""Diagnoses point the right way: a misspelled name gets its nearest match and the whole
list, conflicting options are named as such, and an implausible mass on a vehicle of on/off
valves names the vehicle file's forces, not the built-in Table 2."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from tests.support.cli import run_in_process

EIGHT = Path(__file__).resolve().parents[2] / "vehicles" / "example-8-onoff.toml"


@pytest.mark.parametrize("option, value, near", [
    ("--estimate", "mass,izs", "izz"),
    ("--estimate", "mass,dealy", "delay"),
    ("--estimate", "mass,cxx", "cx"),
    ("--fixed", "mas=2", "mass"),
    ("--initial", "izzz=0.3", "izz"),
])
def test_misspelled_names_get_the_nearest(option, value, near):
    r = run_in_process("estimate", "batch", "nowhere", option, value)
    assert r.returncode != 0 and f"did you mean {near!r}?" in r.stderr, r.stderr
    if option == "--estimate":
        assert "delay, drop" in r.stderr  # the whole list, input parameters included


def test_delay_scan_with_delay_estimated_is_named():
    r = run_in_process("estimate", "batch", "nowhere", "--estimate", "mass,izz,delay",
                       "--delay-scan")
    assert r.returncode != 0 and "--delay-scan profiles a dead time" in r.stderr


def test_implausible_mass_names_the_vehicle_forces(tmp_path):
    run = tmp_path / "run"
    r = run_in_process("sim", "--vehicle", str(EIGHT), "--input", "pulses", "--mass", "23.09",
                       "--izz", "0.31", "--duration", "20", "--pose-rate", "30", "--seed", "1",
                       "--out", str(run))
    assert r.returncode == 0, r.stderr
    big = tmp_path / "big.toml"  # every force typed 100x too large (still within 50 N)
    big.write_text(re.sub(r"force_n = ([0-9.]+)", lambda m: f"force_n = {float(m.group(1)) * 100:.4f}",
                          EIGHT.read_text()).replace("force_sigma_n = 0.005", "force_sigma_n = 0.5"))
    for extra in ([], ["--segments", "5s"]):
        r = run_in_process("estimate", "batch", str(run), "--vehicle", str(big), *extra)
        assert "implausible for an air-table body" in r.stderr, (extra, r.stderr)
        assert "big.toml: its valves' force_n" in r.stderr and "Table 2" not in r.stderr
    r = run_in_process("estimate", "batch", str(run), "--vehicle", str(big), "--segments", "5s",
                       "--json")
    import json

    assert any("implausible" in w for w in json.loads(r.stdout)["warnings"])  # --json too
