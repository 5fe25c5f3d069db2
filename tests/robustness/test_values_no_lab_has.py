"""Values no lab can have are refused at every door with one line naming the unit that
would make them plausible: vehicle.toml, --at, --fixed, --initial (common/plausible_inputs)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from tests.support.cli import run_in_process

ROOT = Path(__file__).resolve().parents[2]
EIGHT = ROOT / "vehicles" / "example-8-onoff.toml"


def _vehicle(tmp: Path, edit) -> Path:
    text = edit(EIGHT.read_text())
    p = tmp / "vehicle.toml"
    p.write_text(text)
    return p


@pytest.mark.parametrize("edit, words", [
    (lambda t: re.sub(r"force_n = ([0-9.]+)", lambda m: f"force_n = {float(m.group(1)) * 1e4}",
                      t, count=1), "gf"),                                # typed 10,000x too large
    (lambda t: re.sub(r"force_n = ([0-9.]+)", "force_n = 0.0002", t, count=1), "outside 0.001-50 N"),
    (lambda t: re.sub(r"force_n = ([0-9.]+)", "force_n = 450", t, count=1), "0.45 N if it is in mN"),
    (lambda t: t.replace("delay_s = 0.0", "delay_s = 86400.0"), "outside 0-2 s"),  # a day
    (lambda t: t.replace("delay_s = 0.0", "delay_s = 30.0"), "0.03 s if it is in ms"),
    (lambda t: t.replace("rise_s = 0.0", "rise_s = 15.0"), "0.015 s if it is in ms"),
])
def test_vehicle_file_values(tmp_path, edit, words):
    v = _vehicle(tmp_path, edit)
    r = run_in_process("estimate", "crlb", str(tmp_path), "--vehicle", str(v))
    assert r.returncode != 0 and words in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr


def test_force_sigma_larger_than_the_force(tmp_path):
    v = _vehicle(tmp_path, lambda t: t.replace("force_sigma_n = 0.005", "force_sigma_n = 5.0", 1))
    r = run_in_process("estimate", "crlb", str(tmp_path), "--vehicle", str(v))
    assert r.returncode != 0 and "a sigma larger than the force" in r.stderr, r.stderr


@pytest.mark.parametrize("option, value, words", [
    ("--at", "mass=0", "mass must be positive"),
    ("--at", "delay=-0.01", "outside 0-2 s"),
    ("--at", "delay=40", "0.04 s if it is in ms"),
    ("--fixed", "izz=0", "izz must be positive"),
    ("--initial", "m=-3", "mass must be positive"),
    ("--at", "drop=-0.1", "drop must be >= 0"),
])
def test_command_line_values(option, value, words):
    cmd = ["estimate", "crlb" if option == "--at" else "batch", "nowhere", option, value]
    r = run_in_process(*cmd)
    assert r.returncode != 0 and words in r.stderr, r.stderr
    assert "Traceback" not in r.stderr


def test_drop_that_makes_forces_negative_at_the_bound(tmp_path):
    from common.errors import UserError
    from common.vehicle import Vehicle
    from estimator.estimate.vehicle_bound import check_at

    v = Vehicle.load(EIGHT)
    n = max(len(i) for i in v.onoff_supplies().values())
    with pytest.raises(UserError, match="every force stays positive"):
        check_at({"drop": 1.0 / (n - 1)}, v)
    check_at({"drop": 0.5 / (n - 1), "mass": 2.0, "delay": 0.05}, v)  # plausible: no error
