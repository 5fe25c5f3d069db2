"""Characterisation sessions against the emulators over ptys."""

import math
import subprocess
import threading

import numpy as np
import pandas as pd
import pytest

from bench.fit import max_error_pct_full_scale
from bench.ohaus.driver import OhausScout
from bench.session import SessionConfig, plan_steps, read_session, run_session, summarize_steps
from bench.valves import ValveController
from common.errors import DeviceError, UserError
from common.thrust_table import ThrustTable
from tests.support.bench import Bench, recorded, run_json
from tests.support.cli import run_in_process


def test_full_session_and_fit_match_table2_within_1pct_full_scale(tpods_exe, tmp_path):
    """Done-when: a full session (short dwell) + fit give Table 2 within 1 % of full scale."""
    b = Bench(seed=11, drift_g_per_s=0.02)  # drift 7x the default, to exercise the correction
    out = tmp_path / "run"
    try:
        v, s = b.paths
        r = subprocess.run([tpods_exe, "bench", "characterize", "--valves", v, "--scale", s,
                            "--dwell", "0.2", "--settle", "0.12", "--zero-settle", "0.1",
                            "--zero-dwell", "0.1", "--out", str(out)],
                           capture_output=True, text=True, timeout=120)
    finally:
        b.stop()
    assert r.returncode == 0, r.stderr
    assert "session success: 36 steps" in r.stdout
    assert "characterise" in r.stderr                      # the progress bar
    meta = run_json(out)
    assert meta["status"] == "success" and meta["valves_closed_confirmed"] is True
    assert meta["devices"]["valves"]["firmware"] == "1.0-emu"
    assert meta["devices"]["scale"]["version"].startswith("SCOUT")
    # every reading the balance sent is in raw.csv, in order (at most the last one or two,
    # in flight when printing stopped, are dropped)
    sent, got = b.sent_weights(), recorded(out / "raw.csv")
    assert got == sent[:len(got)] and len(sent) - len(got) <= 2
    assert meta["counts"]["garbage_lines"] == sum(x.kind == "garbage" for x in b.scout.sent) > 0
    steps = pd.read_csv(out / "steps.csv")
    assert len(steps) == 36 and (steps["n"] >= 10).all()
    assert steps["drift_gf"].iloc[-1] > 0.1                # the drift was there and was removed
    table_path = tmp_path / "fit.toml"
    f = run_in_process("bench", "fit", str(out), "--out", str(table_path), "--reference", "table2")
    assert f.returncode == 0, f.stderr
    fitted = ThrustTable.load(table_path)
    errs = max_error_pct_full_scale(fitted, ThrustTable.default(), np.arange(10.0, 90.01, 0.5))
    assert sorted(errs) == [1, 2, 3, 4]
    print("max error, % of full scale:", errs)
    assert max(errs.values()) < 1.0, errs
    assert fitted.extra["fit"]["nozzles"]["1"]["order"] in (3, 4)
    assert (tmp_path / "fit_orders.png").stat().st_size > 10_000
    assert (tmp_path / "fit_timeseries.png").stat().st_size > 10_000


def _session(b, tmp_path, cfg, **scout_kw):
    v, s = b.paths
    with ValveController(v) as valves, OhausScout(s, **scout_kw) as scale:
        return run_session(valves, scale, cfg, tmp_path / "run", progress=False)


SHORT = SessionConfig(nozzles=(1, 2), duties_pct=(50, 90), dwell_s=0.3, settle_s=0.1,
                      zero_settle_s=0.1, zero_dwell_s=0.1, watchdog_ms=300)


def test_lost_balance_closes_valves_and_marks_failed(bench, tmp_path):
    threading.Timer(0.9, lambda: setattr(bench.scout, "silent", True)).start()
    with pytest.raises(DeviceError, match="went silent"):
        _session(bench, tmp_path, SHORT, silence_timeout=0.3)
    assert bench.valves.duties == (0, 0, 0, 0)
    assert bench.valves.log[-1].cause == "command"          # closed by OFF, not the watchdog
    assert [x[1] for x in bench.valves.lines[-2:]] == ["OFF", "STATE?"]
    meta = run_json(tmp_path / "run")
    assert meta["status"] == "failed" and "silent" in meta["error"]
    assert meta["valves_closed_confirmed"] is True


def test_any_exception_closes_valves(bench, tmp_path, monkeypatch):
    import bench.session as session

    calls = {"n": 0}
    real = session._Recorder.add

    def flaky(self, *a, **k):
        calls["n"] += 1
        if calls["n"] == 60:
            raise RuntimeError("disk full")
        return real(self, *a, **k)

    monkeypatch.setattr(session._Recorder, "add", flaky)
    with pytest.raises(RuntimeError, match="disk full"):
        _session(bench, tmp_path, SHORT)
    assert bench.valves.duties == (0, 0, 0, 0)
    assert bench.valves.lines[-1][1] == "STATE?"
    meta = run_json(tmp_path / "run")
    assert meta["status"] == "failed" and meta["error"] == "disk full"
    raw, steps = read_session(tmp_path / "run")
    assert len(raw) == 59


def test_checks_devices_before_opening(tmp_path):
    b = Bench()
    b.scout.silent = True
    try:
        with pytest.raises(DeviceError, match="sent no reading"):
            _session(b, tmp_path, SHORT, timeout=0.3)
        assert all(not any(c.duties) for c in b.valves.log)   # nothing ever opened
        meta = run_json(tmp_path / "run")
        assert meta["status"] == "failed" and meta["valves_closed_confirmed"] is None
    finally:
        b.stop()
    b = Bench()
    try:
        with pytest.raises(UserError, match="has 4 valves"):
            _session(b, tmp_path / "2", SessionConfig(nozzles=(5,), watchdog_ms=300))
        assert all(not any(c.duties) for c in b.valves.log)
        assert b.scout.command("PV") and not any(x.kind == "weight" for x in b.scout.sent)
    finally:
        b.stop()


def test_session_overhead_is_measured(bench, tmp_path):
    res = _session(bench, tmp_path, SHORT)
    meta = run_json(tmp_path / "run")
    t = meta["timing"]
    assert t["planned_s"] == pytest.approx(4 * 0.4 + 5 * 0.2)
    assert t["elapsed_s"] == pytest.approx(res.elapsed_s)
    assert t["elapsed_s"] >= t["planned_s"]                  # windows are never cut short
    assert math.isfinite(t["loop_overhead_pct"])


def test_plan_and_channels():
    cfg = SessionConfig(nozzles=(1, 3), duties_pct=(20, 40), nozzle_under_test=3)
    steps = plan_steps(cfg, 4)
    assert [s.duties for s in steps] == [(0, 0, 20, 0), (0, 0, 40, 0), (20, 20, 20, 0), (40, 40, 40, 0)]
    with pytest.raises(UserError):
        SessionConfig(duties_pct=(95,))
    with pytest.raises(UserError):
        plan_steps(SessionConfig(nozzle_under_test=5), 4)


def test_summarize_steps_removes_linear_drift_exactly():
    rows = []
    drift = 0.05  # g/s
    t = 0.0
    for w, (phase, step, thrust) in enumerate([("zero", -1, 0), ("dwell", 0, 10.0), ("zero", -1, 0),
                                                ("dwell", 1, 20.0), ("zero", -1, 0)]):
        for _ in range(20):
            rows.append((t, w, phase, step, 1 if step >= 0 else 0, 50.0, thrust + 3.0 + drift * t, 1))
            t += 0.1
    raw = pd.DataFrame(rows, columns=["t_s", "window", "phase", "step", "n_open", "duty_pct",
                                      "reading_gf", "stable"])
    s = summarize_steps(raw)
    np.testing.assert_allclose(s["thrust_gf"], [10.0, 20.0], atol=1e-9)
    np.testing.assert_allclose(s["std_gf"], [0, 0], atol=1e-9)
    assert s["zero_after_gf"].iloc[0] == pytest.approx(3.0 + drift * 4.95)


def test_read_session_errors(tmp_path):
    with pytest.raises(UserError, match="no such run folder"):
        read_session(tmp_path / "nope")
    (tmp_path / "r").mkdir()
    with pytest.raises(UserError, match="raw.csv: not found"):
        read_session(tmp_path / "r")
    (tmp_path / "r" / "raw.csv").write_text("t_s,reading_gf\n0,1\n")
    with pytest.raises(UserError, match="missing column"):
        read_session(tmp_path / "r")
    (tmp_path / "r" / "raw.csv").write_text(
        "t_s,window,phase,step,n_open,duty_pct,reading_gf,stable\n0,0,zero,-1,0,0,nan,1\n")
    with pytest.raises(UserError, match="line 2"):
        read_session(tmp_path / "r")
