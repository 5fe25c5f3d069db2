"""``tpods demo --vehicle F`` (issue 24): the module-run stage on a vehicle, end to end, and
its one-line refusals."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

from tests.support.cli import run as run_cli

ROOT = Path(__file__).resolve().parents[2]
EIGHT = ROOT / "vehicles" / "example-8-onoff.toml"
MAX_LAG_MS = 2.0
"""As tests/tpods/test_plant_vehicle.py: above it (lab ms at scale 4) the machine was too
loaded for the physics to match the recorded commands."""


@pytest.mark.flight
def test_demo_vehicle_end_to_end(tpods_exe, tmp_path):
    out = tmp_path / "demo"
    r = subprocess.run([tpods_exe, "demo", "--vehicle", str(EIGHT), "--mass", "23.09", "--izz",
                        "0.31", "--duration", "24", "--time-scale", "4", "--out", str(out)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    report = (out / "report.md").read_text()
    assert "example-8-onoff" in report and "![batch residuals](batch/batch_residuals.png)" in report
    assert (out / "batch" / "batch_residuals.png").is_file()
    assert (out / "run" / "live" / "vehicle.toml").is_file()
    assert json.loads((out / "run.json").read_text())["status"] == "complete"
    s = json.loads((out / "summary.json").read_text())
    assert [row["source"] for row in s["rows"]] == ["truth (simulation)", "live ls-ekf",
                                                     "batch LS (recorded run)"]
    assert s["live"]["play"]["valves_closed_confirmed"] is True
    if s["live"]["switch_lag_ms"]["mean"] > MAX_LAG_MS:
        pytest.skip(f"this machine is too loaded to judge the estimators: the emulated valves "
                    f"switched {s['live']['switch_lag_ms']['mean']:.1f} lab ms late on average")
    for row in s["rows"][1:]:
        assert abs(row["mass_kg_error_sigmas"]) < 3.5 and abs(row["izz_kgm2_error_sigmas"]) < 3.5, row


@pytest.mark.parametrize("extra, words", [
    (("--structure",), "--vehicle is a variant of its own"),
    (("--method", "ekf"), "--vehicle is estimated live with --method ls-ekf only"),
])
def test_demo_vehicle_refuses_in_one_line(tpods_exe, tmp_path, extra, words):
    r = run_cli(tpods_exe, "demo", "--vehicle", str(EIGHT), *extra, "--out", str(tmp_path / "d"))
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and len(lines) == 1 and words in lines[0], r.stderr
    assert not (tmp_path / "d").exists()
