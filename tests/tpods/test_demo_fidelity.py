"""The demo's duty-time check of its emulated valves (tpods/demo/fidelity.py)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tpods.demo.fidelity import duty_time_error


def _play(tmp_path, rows):
    (tmp_path / "run.json").write_text(json.dumps({"t0_lab": 100.0}))
    (tmp_path / "commands.csv").write_text("t,d1,d2\n" + "".join(f"{r}\n" for r in rows))
    return tmp_path


def test_a_late_close_adds_its_lateness_a_shifted_pulse_nothing(tmp_path):
    play = _play(tmp_path, ["0.0,100,0", "1.0,0,50", "3.0,0,0"])
    # channel 1 open 0..1 s commanded; applied 0..1.05 (closed 50 ms late): +5 %;
    # channel 2 at 50 % 1..3 s commanded, applied 1.02..3.02 (both 20 ms late): 0 %
    sw = [(100.0, (100, 0)), (101.02, (100, 50)), (101.05, (0, 50)), (103.02, (0, 0))]
    e = duty_time_error(sw, play)
    np.testing.assert_allclose(e["per_channel_pct"], [5.0, 0.0], atol=1e-9)
    assert e["max_abs_pct"] == pytest.approx(5.0)


def test_no_switch_at_all_is_all_of_the_impulse_missing(tmp_path):
    play = _play(tmp_path, ["0.0,100,0", "1.0,0,0"])
    e = duty_time_error([], play)
    assert e["per_channel_pct"][0] == pytest.approx(-100.0)
    assert np.isnan(e["per_channel_pct"][1]) and e["max_abs_pct"] == pytest.approx(100.0)
