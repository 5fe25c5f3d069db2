"""`tpods estimate batch --delay-scan` (issue 24, item 7): a run whose valves act 30 ms late
is flagged (structured residuals) and the scan reports the delay with its interval and the
likelihood-ratio test, on stderr and in --json; --delay-scan needs --method ls."""

from __future__ import annotations

import json
from dataclasses import replace

from estimator.batch.delay_scan import shift_commands
from estimator.plant.inputs import phase_sine
from estimator.plant.model import PlantParams
from estimator.plant.sim import SimConfig, simulate, write_sim_run
from tests.support.cli import main_rc


def _delayed_run(path, delay_s=0.030):
    cmd_t, duty = phase_sine(30.0)
    ct, d = shift_commands(cmd_t, duty, delay_s)
    s = simulate(ct, d, PlantParams(2.268, 3.78e-3), config=SimConfig(seed=1))
    keep = s.pose_t <= cmd_t[-1]
    # the run folder holds the commands as sent; the poses are the late valves'
    s = replace(s, cmd_t=cmd_t, duty_pct=duty, thrust_n=s.thrust_n[1:], pose_t=s.pose_t[keep],
                pose=s.pose[keep], states=s.states[keep])
    return write_sim_run(s, path)


_rc = main_rc


def test_delay_scan_finds_the_valve_delay(tmp_path, capsys):
    run = _delayed_run(tmp_path / "r")
    rc, text, err = _rc(["estimate", "batch", str(run), "--delay-scan", "--delay-max-ms", "60",
                         "--json"], capsys)
    assert rc == 0, err
    d = json.loads(text)
    scan = d["delay_scan"]
    lo, hi = scan["interval_s"]
    assert scan["found"] and lo <= 0.030 <= hi and scan["p_value"] < 1e-6, scan
    assert any("structured residuals" in w for w in d["warnings"])
    assert any("valve dead time" in w and "ms" in w for w in d["warnings"])
    assert any(ln.startswith("tpods: warning: the run shows a valve dead time") for ln in err)
    assert d["misfit"]["axes"]["yaw"]["runs_z"] < d["misfit"]["runs_z_limit"]


def test_delay_scan_needs_ls(tmp_path, capsys):
    run = _delayed_run(tmp_path / "r")
    rc, _, err = _rc(["estimate", "batch", str(run), "--method", "ekf", "--delay-scan"], capsys)
    assert rc == 2 and len(err) == 1 and "--delay-scan" in err[0] and "--method ls" in err[0]
