"""Designs and simulations of a vehicle never fall back to the paper's 2.3 kg module in
silence: a vehicle file without [body] needs --mass and --izz."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.support.cli import run_in_process

EIGHT = Path(__file__).resolve().parents[2] / "vehicles" / "example-8-onoff.toml"


@pytest.mark.parametrize("argv", [
    ["design", "--vehicle", str(EIGHT)],
    ["design", "--vehicle", str(EIGHT), "--mass", "23"],
    ["design", "--vehicle", str(EIGHT), "--izz", "0.3"],
    ["sim", "--vehicle", str(EIGHT), "--input", "pulses", "--duration", "4"],
    ["sim", "--vehicle", str(EIGHT), "--input", "pulses", "--duration", "4", "--mass", "23"],
])
def test_a_vehicle_without_body_needs_mass_and_izz(tmp_path, argv):
    r = run_in_process(*argv, "--out", str(tmp_path / "OUT"))
    assert r.returncode != 0
    assert "states no [body] mass_kg and izz_kgm2: give --mass and --izz" in r.stderr, r.stderr
    assert not (tmp_path / "OUT").exists()


def test_a_vehicle_with_body_values_designs(tmp_path):
    v = tmp_path / "v.toml"
    v.write_text(EIGHT.read_text() + "\n[body]\nmass_kg = 23.09\nizz_kgm2 = 0.31\n")
    r = run_in_process("sim", "--vehicle", str(v), "--input", "pulses", "--duration", "2",
                       "--out", str(tmp_path / "S"))
    assert r.returncode == 0, r.stderr
    import json

    truth = json.loads((tmp_path / "S" / "run.json").read_text())["truth"]
    assert truth["mass_kg"] == 23.09 and truth["izz_kgm2"] == 0.31


def test_the_tpods_module_as_a_vehicle_is_the_papers_module(tmp_path):
    """vehicles/tpods.toml is the paper's module: its defaults are its own."""
    tpods = EIGHT.parent / "tpods.toml"
    r = run_in_process("sim", "--vehicle", str(tpods), "--duration", "2", "--out", str(tmp_path / "S"))
    assert r.returncode == 0, r.stderr
