"""A clock offset between the mocap host and the player's host: measured from the streams,
and, once applied (``clock_offset_s``), the dead time fitted on the recorded run is the
valves' own (none here) instead of the offset."""

from __future__ import annotations

import json

import numpy as np
import pytest

from common.runfolder import warn_if_mixed_clock
from common.thrust_table import ThrustTable
from estimator.live.config import LiveConfig
from estimator.live.core import LiveEstimator
from estimator.live.recorder import LiveRecorder
from tests.support.cli import main_rc
from tests.support.sim import sim_run

OFFSET_S = 0.020  # the mocap host's clock ahead of the player's


def _record(out, offset_given_s: float, *, auto: bool = False, offset_s: float = OFFSET_S,
            duration: float = 30.0, notes: list[str] | None = None):
    """A simulated 30 s run through the live estimator into ``out``: poses stamped by a
    clock ``offset_s`` (20 ms) ahead; every message arrives 0.3 ms plus an exponential delay (mean 1 ms)
    after it was stamped (by the right clock). ``auto``: the measured offset is applied
    once settled; ``notes`` collects what the estimator says of it."""
    run = sim_run(2.268, 3.78e-3, 1, duration=duration)
    rng = np.random.default_rng(2)
    rec = LiveRecorder(out, {"kind": "live-estimate"})
    est = LiveEstimator(ThrustTable.default(), LiveConfig(clock_offset_s=offset_given_s,
                                                               clock_offset_auto=auto),
                        recorder=rec)
    if notes is not None:
        est.on_note = notes.append
    events = sorted([(t, 1, i) for i, t in enumerate(run.cmd_t)]
                    + [(t, 0, i) for i, t in enumerate(run.pose_t)])
    for seq, (t, kind, i) in enumerate(events):
        if kind:
            est.command({"body": "tpods1", "t": float(t), "duty": list(run.duty_pct[i]),
                         "kind": "set", "seq": seq}, float(t) + 3e-4 + rng.exponential(1e-3))
        else:
            x, y, psi = run.pose[i]
            est.pose({"body": "tpods1", "frame": i + 1, "t": float(t) + offset_s, "x": x, "y": y,
                      "yaw": psi, "occluded": False}, float(t) + 3e-4 + rng.exponential(1e-3))
        est.process(float(t) + 1e-3)
    est.finish()
    summary = est.summary()
    rec.close("success", {"final": summary})
    return summary


def _scan(run_dir, capsys, window: str | None = None) -> dict:
    rc, text, err = main_rc(["estimate", "batch", str(run_dir), "--delay-scan",
                             "--delay-max-ms", "60", "--json",
                             *(() if window is None else ("--window", window))], capsys)
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


def test_a_settled_offset_is_applied_once_and_the_residual_reported(tmp_path):
    """--clock-offset-ms auto: the 20 ms is measured within 2 ms, applied from the sixth
    second on (said once), the two poses in the clocks' overlap skipped, and the offset
    left afterwards is measured as about none; the filter runs on undisturbed."""
    notes: list[str] = []
    s = _record(tmp_path / "auto", 0.0, auto=True, duration=12.0, notes=notes)
    a = s["clock_offset_applied"]
    assert abs(s["clock_offset_ms"] - 20.0) < 2.0 and abs(a["offset_ms"] - 20.0) < 2.0, a
    assert a["windows"] >= 5 and 4.0 < a["from_pose_t_s"] < 8.0, a
    assert a["poses_skipped_in_overlap"] <= 3 and abs(a["residual_ms"]) < 1.0, a
    assert len(notes) == 1 and "+20.0" in notes[0] and "applied" in notes[0], notes
    assert not s["diverged"] and abs(s["mass_kg"] - 2.268) < 5 * s["mass_sigma_kg"], s
    meta = json.loads((tmp_path / "auto" / "run.json").read_text())
    assert meta["final"]["clock_offset_applied"]["offset_ms"] == a["offset_ms"]
    # reading the recording says that its pose times step where the offset was applied
    at = a["from_pose_t_s"] - meta["t0_lab"]
    line = warn_if_mixed_clock(tmp_path / "auto", meta)
    assert line is not None and f"{a['offset_ms']:+.2f} ms" in line and f"--window 0:{at:.3f}" in line
    assert warn_if_mixed_clock(tmp_path / "auto", {"final": {"clock_offset_applied": None}}) is None


def test_no_offset_nothing_applied(tmp_path):
    """With the clocks agreeing nothing is applied and nothing said."""
    notes: list[str] = []
    s = _record(tmp_path / "none", 0.0, auto=True, offset_s=0.0, duration=12.0, notes=notes)
    assert s["clock_offset_windows"] >= 10 and abs(s["clock_offset_ms"]) < 1.0, s
    assert s["clock_offset_applied"] is None and s["clock_offset_auto"] and notes == []


@pytest.mark.slow
def test_offset_applied_live_unbiases_the_dead_time_after_it(tmp_path, capsys):
    """The measured offset applied during the run: the dead time fitted on the poses after
    the change is the valves' own (none), where the poses before it show the 20 ms."""
    s = _record(tmp_path / "auto", 0.0, auto=True)
    t_a = s["clock_offset_applied"]["from_pose_t_s"]
    before = _scan(tmp_path / "auto", capsys, f"0:{t_a - 0.1:.3f}")
    after = _scan(tmp_path / "auto", capsys, f"{t_a + 0.1:.3f}:30")
    lo, hi = before["interval_s"]
    assert before["found"] and lo <= OFFSET_S <= hi, before
    lo, hi = after["interval_s"]
    assert not after["found"] and lo <= 0.0 <= hi + 1e-3 and after["best_s"] < 0.003, after
