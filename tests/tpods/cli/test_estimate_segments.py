"""``tpods estimate batch --segments/--thruster-health`` and ``calibrate thrust --segments``
as a user meets them: one clear line for each mistake, the JSON a script reads."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.support.cli import run_in_process

EIGHT = Path(__file__).resolve().parents[3] / "vehicles" / "example-8-onoff.toml"


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("seg") / "run"
    r = run_in_process("sim", "--vehicle", str(EIGHT), "--input", "pulse-groups", "--mass", "23.09",
                       "--izz", "0.31", "--duration", "40", "--pose-rate", "30", "--seed", "2",
                       "--noise-pos", "0.003", "--noise-yaw-deg", "0.3", "--out", str(out))
    assert r.returncode == 0, r.stderr
    return out


@pytest.mark.parametrize("extra, words", [
    (["--out-vehicle", "x.toml"], "--out-vehicle writes the verdicts of --thruster-health"),
    (["--exclude", "1:2"], "--exclude leaves stretches out of a fit by segments"),
    (["--segments", "five"], "give a length in seconds"),
    (["--segments", "5s", "--exclude", "3:1"], "T1 must be after T0"),
    (["--segments", "5s", "--method", "ekf"], "drop --method ekf"),
    (["--thruster-health", "--model", "auto"], "--model auto chooses the model of the mass fit"),
    (["--thruster-health", "--out-vehicle", "x.txt"], "give a .toml file name"),
])
def test_mistakes_one_line(run_dir, tmp_path, extra, words):
    r = run_in_process("estimate", "batch", str(run_dir), *extra, cwd=tmp_path)
    assert r.returncode != 0
    assert words in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_segments_json(run_dir):
    r = run_in_process("estimate", "batch", str(run_dir), "--segments", "5s", "--sigma-pos",
                       "0.003", "--sigma-yaw-deg", "0.3", "--json")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["method"] == "ls-segments" and out["converged"]
    assert out["segments"]["n"] == 8 and out["segments"]["length_s"] == 5.0
    m = out["params"]["mass"]
    assert set(m) >= {"value", "noise", "clustered", "thrust", "total"}
    assert abs(m["value"] - 23.09) < 3 * m["total"]
    assert "too few for a clustered sigma" in out["sigma_terms"]  # 8 segments


def test_calibrate_thrust_segments_refuses_a_table(run_dir, tmp_path):
    r = run_in_process("calibrate", "thrust", str(run_dir), "--mass", "23.09", "--segments",
                       "auto", "--per", "common", "--out", str(tmp_path / "v.toml"))
    assert r.returncode != 0 and "drop --per common" in r.stderr
