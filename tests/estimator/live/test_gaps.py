"""Gaps named by the live estimator (estimator/live/gaps.py): frame jumps and late poses,
lost commands as unknown input, and the filter across such an input gap."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from estimator.live.gaps import GapTracker, forget_motion, gap_sentence, gap_warnings


def test_pose_gaps_missing_and_late(tmp_path):
    g = GapTracker(silence_s=0.5, csv_path=tmp_path / "gaps.csv")
    arr = 100.0
    for f in range(1, 11):  # 100 Hz, on time
        assert g.pose(f, f * 0.01, arr + f * 0.01) is None
    lost = g.pose(15, 0.15, arr + 0.15)  # frames 11-14 lost
    assert (lost.missing, lost.before, lost.after) == (4, 10, 15)
    assert lost.t_start == pytest.approx(0.10) and lost.t_end == pytest.approx(0.15)
    late = g.pose(16, 0.16, arr + 2.2)  # none lost, 2 s late (a TCP replay)
    assert late.missing == 0 and late.silent_s == pytest.approx(2.05)
    assert g.pose(16, 0.16, arr + 2.3) is None  # a repeat is not a gap
    assert g.missing("poses") == 4
    rows = list(csv.DictReader((tmp_path / "gaps.csv").open()))
    assert [(r["stream"], r["missing"]) for r in rows] == [("poses", "4"), ("poses", "0")]
    assert "4 missing" in gap_sentence(g.rows()[0]) and "late" in gap_sentence(g.rows()[1])


def test_short_gaps_are_counted_in_one_warning_line():
    """A replayed run's dropped frames (one at a time) are one line; a long gap its own."""
    g = GapTracker()
    f = 0
    for k in range(200):
        f += 2 if k % 10 == 5 else 1  # every tenth frame dropped
        g.pose(f, f * 0.01, f * 0.01)
    g.pose(f + 50, (f + 50) * 0.01, (f + 50) * 0.01)  # 49 frames lost: 0.5 s
    lines = gap_warnings(g.rows())
    assert len(lines) == 2
    assert "49 missing" in lines[0]
    assert lines[1].startswith("poses: 20 short gaps") and "20 missing in all" in lines[1]
    s = g.summary()
    assert s["gap_count"] == 21 and s["poses_missing"] == 69 and len(s["gaps"]) == 21


def test_lost_commands_make_an_interval_of_unknown_input():
    g = GapTracker()
    assert g.command("b", 1, 1.0, 1.0) is None
    assert g.command("b", 2, 1.1, 1.1) is None
    assert not g.input_unknown(0.0, 5.0)
    gap = g.command("b", 7, 1.6, 1.6)  # 3..6 lost
    assert gap.stream == "commands" and gap.missing == 4
    assert g.input_unknown(1.05, 1.2) and g.input_unknown(1.5, 1.7)
    assert not g.input_unknown(1.6, 2.0) and not g.input_unknown(0.5, 1.1)
    # a hold re-announced late, none lost: named (silence) but the input is known
    late = g.command("b", 8, 1.7, 3.0)
    assert late.missing == 0 and not g.input_unknown(1.65, 1.75)
    assert g.command("b", None, 2.0, 3.1) is None  # no seq: nothing to tell


def test_forget_motion_keeps_the_parameters_and_decouples_them():
    P = np.full((8, 8), 1e-4) + np.eye(8) * 1e-3
    P0 = np.diag(np.square([0.1, 0.1, 0.09, 0.1, 0.1, 0.035, 1.0, 5e-3]))
    before = P[6:, 6:].copy()
    forget_motion(P, P0, 1.0, acc_max=0.3, alpha_max=20.0)
    assert np.array_equal(P[6:, 6:], before)
    assert not P[:6, 6:].any() and not P[6:, :6].any()
    assert P[3, 3] == pytest.approx(0.3 ** 2) and P[5, 5] == pytest.approx(20.0 ** 2)
    assert P[2, 2] == pytest.approx(np.pi ** 2)  # yaw at most pi
    assert P[0, 0] == pytest.approx(0.15 ** 2)


def test_live_filter_across_lost_commands_stays_consistent():
    """A simulated run whose commands over 1 s are lost (the poses too): without the
    unknown input the filter takes the held command for the truth and its mass moves by
    many sigma; with it the estimate stays within 3 sigma of the same run with no loss."""
    from common.thrust_table import ThrustTable
    from estimator.live.core import LiveEstimator
    from tests.support.sim import sim_run

    run = sim_run(2.268, 3.78e-3, 3, duration=14.0, drop=0.0)
    table = ThrustTable.default()

    def live(lose: tuple[float, float] | None, seq_jump: bool = True):
        """The live estimator fed the run in time order (``lose``: nothing in that span;
        ``seq_jump`` False: the commands carry no usable numbering)."""
        est = LiveEstimator(table, body="tpods1")
        t_cmd, duty = run.cmd_t, run.duty_pct
        events = [(t, 1, i) for i, t in enumerate(t_cmd)] + [(t, 0, i) for i, t in enumerate(run.pose_t)]
        events.sort()
        seq = 0
        for t, kind, i in events:
            gone = lose is not None and lose[0] < t < lose[1]
            if kind == 1:
                seq += 1
                if gone:
                    continue
                est.command({"body": "tpods1", "t": float(t), "duty": list(duty[i]), "kind": "set",
                             "seq": seq if seq_jump else 0}, float(t))
            elif not gone:
                x, y, psi = run.pose[i]
                est.pose({"body": "tpods1", "frame": i + 1, "t": float(t), "x": x, "y": y,
                          "yaw": psi, "occluded": False}, float(t))
            est.process(float(t) + 0.01)
        est.finish()
        return est.summary()

    full = live(None)
    gap = live((6.0, 7.0))
    assert sorted(g["stream"] for g in gap["gaps"]) == ["commands", "poses"]
    assert gap["counters"]["motion_resets"] >= 1
    assert not gap["diverged"]
    assert abs(gap["mass_kg"] - full["mass_kg"]) < 3 * gap["mass_sigma_kg"]
    assert abs(gap["izz_kgm2"] - full["izz_kgm2"]) < 3 * gap["izz_sigma_kgm2"]
    assert gap["mass_sigma_kg"] >= full["mass_sigma_kg"]  # the gap's information is gone
    # the same loss with no numbering to reveal it: the held command taken for the truth
    blind = live((6.0, 7.0), seq_jump=False)
    assert blind["diverged"] or abs(blind["izz_kgm2"] - full["izz_kgm2"]) > 10 * blind["izz_sigma_kgm2"]


def test_clock_offset_from_the_lower_envelopes_of_the_delays():
    """Mocap clock 20 ms ahead of the player's, one-way delays 0.3 ms plus exponential
    queueing (mean 2 ms): measured within 0.5 ms, with a sigma that covers it."""
    from estimator.live.clock_offset import OffsetMeter

    rng = np.random.default_rng(4)
    m = OffsetMeter()
    for k in range(12 * 100):  # 12 s of 100 Hz poses and 50 Hz commands
        t = 1000.0 + k * 0.01
        m.pose(t + 0.020, t + 3e-4 + rng.exponential(2e-3))
        if k % 2 == 0:
            m.command(t, t + 3e-4 + rng.exponential(2e-3))
    est = m.estimate()
    assert est.windows >= 10
    assert abs(est.offset_s - 0.020) < 5e-4
    assert abs(est.offset_s - 0.020) < 4 * est.sigma_s + 2e-4
    assert OffsetMeter().estimate() is None
