"""A clock offset between the mocap host and the player's host: measured from the streams,
and, once applied (``clock_offset_s``), the dead time fitted on the recorded run is the
valves' own (none here) instead of the offset."""

from __future__ import annotations

import json

import numpy as np
import pytest

from common.thrust_table import ThrustTable
from estimator.live.config import LiveConfig
from estimator.live.core import LiveEstimator
from estimator.live.recorder import LiveRecorder
from tests.support.cli import main_rc
from tests.support.sim import sim_run

OFFSET_S = 0.020  # the mocap host's clock ahead of the player's


def _record(out, offset_given_s: float):
    """A simulated 30 s run through the live estimator into ``out``: poses stamped by a
    clock 20 ms ahead; every message arrives 0.3 ms plus an exponential delay (mean 1 ms)
    after it was stamped (by the right clock)."""
    run = sim_run(2.268, 3.78e-3, 1, duration=30.0)
    rng = np.random.default_rng(2)
    rec = LiveRecorder(out, {"kind": "live-estimate"})
    est = LiveEstimator(ThrustTable.default(), LiveConfig(clock_offset_s=offset_given_s),
                        recorder=rec)
    events = sorted([(t, 1, i) for i, t in enumerate(run.cmd_t)]
                    + [(t, 0, i) for i, t in enumerate(run.pose_t)])
    for seq, (t, kind, i) in enumerate(events):
        if kind:
            est.command({"body": "tpods1", "t": float(t), "duty": list(run.duty_pct[i]),
                         "kind": "set", "seq": seq}, float(t) + 3e-4 + rng.exponential(1e-3))
        else:
            x, y, psi = run.pose[i]
            est.pose({"body": "tpods1", "frame": i + 1, "t": float(t) + OFFSET_S, "x": x, "y": y,
                      "yaw": psi, "occluded": False}, float(t) + 3e-4 + rng.exponential(1e-3))
        est.process(float(t) + 1e-3)
    est.finish()
    summary = est.summary()
    rec.close("success", {"final": summary})
    return summary


def _scan(run_dir, capsys) -> dict:
    rc, text, err = main_rc(["estimate", "batch", str(run_dir), "--delay-scan",
                             "--delay-max-ms", "60", "--json"], capsys)
    assert rc == 0, err
    return json.loads(text)["delay_scan"]


@pytest.mark.slow
def test_offset_measured_then_applied_unbiases_the_dead_time(tmp_path, capsys):
    raw = _record(tmp_path / "raw", 0.0)
    assert abs(raw["clock_offset_ms"] - 20.0) < 2.0  # measured within 2 ms
    fixed = _record(tmp_path / "fixed", raw["clock_offset_ms"] * 1e-3)
    assert abs(fixed["clock_offset_ms"]) < 2.0 and fixed["clock_offset_given_ms"] > 18.0
    before, after = _scan(tmp_path / "raw", capsys), _scan(tmp_path / "fixed", capsys)
    lo, hi = before["interval_s"]
    assert before["found"] and lo <= OFFSET_S <= hi, before  # the offset taken for a dead time
    lo, hi = after["interval_s"]
    assert not after["found"] and lo <= 0.0 <= hi + 1e-3 and after["best_s"] < 0.003, after
