"""The pendulum check's verdict in the ground truth from parts (calibrate combine)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from calibration.composite import combine, load_parts, plausibility_warnings
from calibration.swing.pendulum_check import check_series, simulate_series
from common.errors import UserError
from tests.support.cli import run_in_process

EXAMPLE = Path(__file__).resolve().parents[2] / "calibration" / "examples" / "truss_two_modules.toml"
RADII = np.arange(0.25, 0.751, 0.05)

PARTS = """
pendulum_check = "{top}"
[[part]]
name = "module A"
mass_kg = 0.72
izz_kgm2 = 1.2e-3
position_m = [-0.4, 0.0]
[[part]]
name = "module B"
mass_kg = 0.72
izz_kgm2 = 1.2e-3
position_m = [0.4, 0.0]
{own}
[[part]]
name = "stick"
mass_kg = 0.06
shape = "rod"
length_m = 0.64
position_m = [0.0, 0.0]
"""


def _check(path: Path, scale: float) -> Path:
    izz = scale * simulate_series(0.2345, 0.02094, RADII, 3e-5, seed=4)
    path.write_text(json.dumps(check_series(RADII, izz, np.full_like(RADII, 3e-5), 0.02094).to_dict()))
    return path


def test_the_verdict_goes_into_the_ground_truth_and_a_failure_warns(tmp_path):
    _check(tmp_path / "good.json", 1.0)
    _check(tmp_path / "bad.json", 0.9)
    f = tmp_path / "parts.toml"
    f.write_text(PARTS.format(top="good.json", own='pendulum_check = "bad.json"'))
    parts, about = load_parts(f)
    res = combine(parts, about)
    d = res.to_dict()
    by_file = {Path(c["file"]).name: c for c in d["pendulum_checks"]}
    assert by_file["good.json"]["verdict"] == "pass" and by_file["good.json"]["parts"] == ["module A"]
    assert by_file["bad.json"]["verdict"] == "fail" and by_file["bad.json"]["parts"] == ["module B"]
    w = plausibility_warnings(parts, res)
    assert len(w) == 1 and "'module B'" in w[0] and "failed its test-mass check" in w[0]


def test_without_a_check_the_result_is_unchanged():
    assert "pendulum_checks" not in combine(*load_parts(EXAMPLE)).to_dict()


def test_a_missing_or_foreign_check_file_is_refused(tmp_path):
    f = tmp_path / "parts.toml"
    f.write_text(PARTS.format(top="nope.json", own=""))
    with pytest.raises(UserError, match="nope.json: file not found"):
        load_parts(f)
    (tmp_path / "other.json").write_text('{"mass_kg": 1}')
    f.write_text(PARTS.format(top="other.json", own=""))
    with pytest.raises(UserError, match="not a pendulum check"):
        load_parts(f)


def test_combine_json_carries_the_verdict(tpods_exe, tmp_path):
    _check(tmp_path / "good.json", 1.0)
    f = tmp_path / "parts.toml"
    f.write_text(PARTS.format(top="good.json", own=""))
    r = run_in_process("calibrate", "combine", str(f), "--json")
    assert r.returncode == 0, r.stderr
    chk = json.loads(r.stdout)["pendulum_checks"]
    assert chk[0]["verdict"] == "pass" and chk[0]["parts"] == ["module A", "module B"]
