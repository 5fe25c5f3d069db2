"""``tpods demo --quick``: the whole lab day end to end (about 45 s on an idle 2-core machine)."""

from __future__ import annotations

import json
import subprocess

import pytest


@pytest.mark.flight
def test_demo_quick_writes_the_report(tpods_exe, tmp_path):
    out = tmp_path / "demo"
    r = subprocess.run([tpods_exe, "demo", "--quick", "--out", str(out)], capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "summary" in r.stdout and "time scale 2" in r.stdout
    s = json.loads((out / "summary.json").read_text())
    rows = {row["source"]: row for row in s["rows"]}
    assert set(rows) >= {"truth (simulation)", "balance + bifilar", "batch LS (recorded run)",
                         "batch LS, true table (check)"}
    # the ground-truth instruments and the batch fit with the true table find the truth
    assert abs(rows["balance + bifilar"]["mass_error_sigmas"]) < 3
    assert abs(rows["balance + bifilar"]["izz_error_sigmas"]) < 3
    chk = rows["batch LS, true table (check)"]
    assert abs(chk["mass_error_pct"]) < 1 and abs(chk["izz_error_pct"]) < 1
    assert s["live"]["play"]["valves_closed_confirmed"] is True
    # the demo measures how late its emulated valves switched (both runs at time scale 2)
    lags = {"calibration": s["calibration"]["switch_lag_ms"], "run": s["live"]["switch_lag_ms"]}
    assert all(lag["n"] > 0 for lag in lags.values()), lags
    timings = s["timings_s"]
    assert set(timings) >= {"characterisation + fit", "calibration run + fit", "module run (live)",
                            "batch", "total"}
    assert json.loads((out / "run.json").read_text())["timings_s"]["total"] > 0
    worst = max(lag["mean"] for lag in lags.values())
    if worst > 5.0:  # as test_demo_structure.py: the physics no longer match the commands
        pytest.skip(f"this machine is too loaded to judge the estimators: the emulated valves "
                    f"switched {worst:.1f} lab ms after the player's stamps on average")
    late = max(lag["max"] for lag in lags.values())
    if late > 100.0:  # one valve change a tenth of a second late (426 ms seen at load 7):
        # the batch fit of the run diverged on it while the check at the plant's switch times
        # found the truth
        pytest.skip(f"this machine is too loaded to judge the estimators: an emulated valve "
                    f"switched {late:.0f} lab ms after the player's stamp")
    # issue 17: the calibration finds the weak thruster, and after it the batch estimate's
    # error lies within 3 TOTAL sigma (noise + thrust table), the parts shown beside it
    factors = {f["name"]: f for f in s["calibration"]["factors"]}
    # the flight opens each valve a few dozen times: one late close on a loaded machine moves
    # a factor by more than its sigma while the mean lag stays small (tpods/demo/fidelity.py)
    open_err = s["calibration"]["duty_time_error"]["max_abs_pct"]
    if open_err > 100.0 * min(f["sigma"] for f in factors.values()):
        pytest.skip(f"this machine is too loaded to judge the calibration: an emulated valve was "
                    f"open {open_err:.2g} % longer or shorter than commanded")
    assert set(factors) == {f"efficiency.{j}" for j in range(1, 5)}
    for f in factors.values():  # 4 sigma: the emulated valves' timing jitter on a busy machine
        assert abs(f["value"] - f["truth"]) < 4 * f["sigma"], f
    assert factors["efficiency.3"]["value"] < min(factors[f"efficiency.{j}"]["value"] for j in (1, 2, 4))
    after = rows["batch LS (recorded run)"]
    assert after["converged"] and after["mass_sigma_thrust_kg"] > after["mass_sigma_noise_kg"]
    assert abs(after["mass_error_sigmas"]) < 3 and abs(after["izz_error_sigmas"]) < 3
    assert any(src.startswith("batch LS, bench table (before calibration)") for src in rows)
    report = (out / "report.md").read_text()
    figs = [line.split("(")[1].rstrip(")") for line in report.splitlines() if line.startswith("![")]
    assert len(figs) >= 6 and all((out / f).is_file() for f in figs)


def test_switch_lag_is_the_gap_to_the_nearest_command_with_the_same_duties(tmp_path):
    from tpods.demo.procs import switch_lag_ms

    (tmp_path / "run.json").write_text(json.dumps({"t0_lab": 100.0}))
    (tmp_path / "commands.csv").write_text("t,d1,d2\n0.0,50,0\n0.5,0,50\n1.0,50,0\n3.0,0,50\n")
    # 1 ms after the first command, 3 ms after the second, 2 ms before the third, 4 ms after
    # the fourth (not the second, with the same duties)
    lag = switch_lag_ms([(100.001, (50, 0)), (100.503, (0, 50)), (100.998, (50, 0)),
                         (103.004, (0, 50))], tmp_path)
    assert lag["n"] == 4
    assert lag["mean"] == pytest.approx(2.5, abs=1e-6)
    assert lag["max"] == pytest.approx(4.0, abs=1e-6)
    assert switch_lag_ms([(100.0, (10, 10))], tmp_path)["n"] == 0
    # more than 1 s from any command with its duties: still the nearest of them
    assert switch_lag_ms([(102.5, (50, 0))], tmp_path)["mean"] == pytest.approx(1500.0, abs=1e-6)


def test_stage_times_table_and_run_json(capsys):
    from tpods.demo.timing import StageTimes

    meta: dict = {}
    times = StageTimes(meta)
    with times.stage("1/2 first", "first"):
        pass
    times.paced("first", 0.0)
    with pytest.raises(RuntimeError), times.stage("2/2 second", "second"):
        raise RuntimeError("a failed stage keeps its time")
    assert "== 1/2 first" in capsys.readouterr().out
    assert set(meta["timings_s"]) == {"first", "second", "total"}
    lines = times.lines()
    assert lines[0].split()[:3] == ["stage", "wall", "[s]"]
    assert [ln.split()[0] for ln in lines[1:]] == ["first", "second", "total"]
    assert lines[2].split()[2:] == ["-", "-"]  # nothing paced in the second stage
    md = times.lines(markdown=True)
    assert md[0].startswith("| stage |") and len(md) == len(lines) + 1
