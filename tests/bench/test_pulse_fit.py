"""On/off pulse fits (bench.pulse_fit) on simulated HX711 logs: known force per valve, dead
time, rise, noise and sample-and-hold, imported as `tpods bench import` does."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bench.loadcell_import import read_log
from bench.pulse_fit import fit_pulses, hold_runs, is_pulse_session, update_period
from bench.session import summarize_steps
from common.thrust_table import GF_TO_N
from tests.support.pulse_logs import pulse_log

FORCES_G = {1: 45.0, 2: 38.0}


def _fit(path, **kw):
    log = read_log(path, settle_s=1.5, zero_settle_s=1.5)
    return log, fit_pulses(log.raw, summarize_steps(log.raw), **kw)


def test_simulated_pulses_recover_force_delay_and_rise_within_their_sigma_over_seeds(tmp_path):
    pulls = {"force": [], "delay": [], "rise": []}
    for seed in range(5):
        log, res = _fit(pulse_log(tmp_path / f"p{seed}.csv", FORCES_G, 0.08, 0.15, seed=seed))
        assert log.on_off and is_pulse_session(log.raw)
        assert res.update_period_s == pytest.approx(1 / 8.3, abs=0.021)  # 6 rows at 50 Hz
        for v, f in FORCES_G.items():
            r = res.valves[v]
            assert r["n_pulses"] == 3 and r["n_opening_edges"] == 3 and r["n_closing_edges"] == 3
            pulls["force"].append((r["force_n"] - f * GF_TO_N) / r["force_sigma_n"])
            pulls["delay"].append((r["delay_s"] - 0.08) / r["delay_sigma_s"])
            pulls["rise"].append((r["rise_s"] - 0.15) / r["rise_sigma_s"])
            assert r["close_delay_s"] == pytest.approx(0.08, abs=4 * r["close_delay_sigma_s"])
            assert r["fall_s"] == pytest.approx(0.15, abs=4 * r["fall_sigma_s"])
        both = res.counts[2]
        assert both["valve_sets"] == ["1,2"] and both["n_pulses"] == 2
        assert both["force_n"] == pytest.approx(83.0 * GF_TO_N, abs=3 * both["force_sigma_n"])
    for name, p in pulls.items():
        p = np.abs(p)
        assert np.all(p < 3.0) and np.mean(p) < 1.5, (name, p)


def test_an_edge_faster_than_the_amplifier_gets_its_update_period_as_timing_floor(tmp_path):
    _, res = _fit(pulse_log(tmp_path / "fast.csv", FORCES_G, 0.05, 0.02, seed=1, update_hz=5.0))
    r = res.valves[1]
    assert r["delay_sigma_s"] >= 0.2 / math.sqrt(12) - 1e-9
    assert abs(r["delay_s"] - 0.05) < 3 * r["delay_sigma_s"]
    assert any("held for" in w for w in res.warnings)


def test_hold_runs_and_update_period():
    t = np.arange(0, 2, 0.02)
    y = np.floor(t / 0.12)  # a new value every 120 ms
    ts, ys, dur = hold_runs(t, y)
    assert len(ts) == len(np.unique(y)) and math.isnan(dur[-1])
    assert update_period(t, y) == pytest.approx(0.12, abs=0.021)


def test_scale_rel_widens_the_force_sigma(tmp_path):
    path = pulse_log(tmp_path / "p.csv", FORCES_G, 0.08, 0.15, seed=2)
    _, a = _fit(path)
    _, b = _fit(path, scale_rel=0.01)
    assert b.valves[1]["force_sigma_n"] > 0.009 * b.valves[1]["force_n"] > a.valves[1]["force_sigma_n"]
    assert not any("scale-rel" in w for w in b.warnings)
