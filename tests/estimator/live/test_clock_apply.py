"""When a measured clock offset is applied (estimator/live/clock_apply.py), and what is
said of it (estimator/live/clock_report.py)."""

from __future__ import annotations

from estimator.live.clock_apply import OffsetApplier
from estimator.live.clock_offset import OffsetEstimate
from estimator.live.clock_report import clock_offset_lines


def test_settled_only_with_enough_agreeing_windows_and_a_clear_offset():
    a = OffsetApplier()
    assert a.settled(OffsetEstimate(0.020, 1e-5, 5))
    assert not a.settled(OffsetEstimate(0.020, 1e-5, 4))     # too few windows
    assert not a.settled(OffsetEstimate(0.0005, 1e-6, 30))   # below 1 ms: the paths' asymmetry
    assert not a.settled(OffsetEstimate(0.020, 3e-3, 30))    # sigma not small against it
    assert not a.settled(OffsetEstimate(0.020, 1e-3, 100))   # windows disagree (10 ms spread)
    assert not OffsetApplier(enabled=False).settled(None)


def test_applied_once_then_poses_shifted_and_the_overlap_skipped():
    a = OffsetApplier()
    assert a.pose_time(10.00, 10.0) == (10.00, False)
    a.consider(OffsetEstimate(0.020, 1e-5, 6), 10.005)
    a.consider(OffsetEstimate(0.030, 1e-5, 7), 10.006)  # once only
    assert a.take_news() and not a.take_news()
    t, skip = a.pose_time(10.01, 10.01)
    assert skip and abs(t - 9.99) < 1e-12 and a.skipped == 1
    t, skip = a.pose_time(10.03, 10.03)
    assert not skip and abs(t - 10.01) < 1e-12 and a.at_t_s == t
    d = a.as_dict()["clock_offset_applied"]
    assert abs(d["offset_ms"] - 20.0) < 1e-9 and d["windows"] == 6


def test_an_unmeasured_offset_is_warned_about_where_the_valve_delay_sigma_is_stated():
    s = {"clock_offset_ms": None, "clock_offset_given_ms": 0.0,
         "counters": {"poses_rx": 50, "cmds_rx": 0}}
    info, warn = clock_offset_lines(s, delay_sigma_s=0.002)
    assert not info and len(warn) == 1 and "unmeasured" in warn[0] and "2 ms" in warn[0]
    assert "--clock-offset-ms" in warn[0] and "tpods run play" in warn[0]
    assert clock_offset_lines(s, delay_sigma_s=None) == ([], [])
    assert clock_offset_lines({**s, "clock_offset_given_ms": 5.0}, 0.002) == ([], [])


def test_a_ping_is_reported_beside_the_envelope():
    s = {"clock_offset_ms": -20.1, "clock_offset_sigma_ms": 0.05, "clock_offset_windows": 9,
         "clock_ping_player": {"key": "tpods/tpods1/clock", "asked": 20, "answered": 20,
                               "offset_ms": 20.0, "sigma_ms": 0.01, "rtt_min_ms": 0.1,
                               "kept": 5}}
    info, warn = clock_offset_lines(s)
    assert "round trip: +20.00" in info[0] and "-20.10" in info[1] and "differ by -20.1" in warn[0]


def test_the_clock_offset_option_takes_auto_none_or_ms(capsys):
    """``--clock-offset-ms``: auto, none or a finite number; anything else one line, exit 2."""
    import argparse

    import pytest

    from common.argtypes import clock_offset_arg

    assert clock_offset_arg("AUTO") == "auto" and clock_offset_arg("none") == "none"
    assert clock_offset_arg("-19.5") == -19.5
    for bad in ("soon", "nan", "inf"):
        with pytest.raises(argparse.ArgumentTypeError, match="auto, none or a"):
            clock_offset_arg(bad)
    from tests.support.cli import main_rc

    rc, _, err = main_rc(["estimate", "live", "--clock-offset-ms", "soon"], capsys)
    assert rc == 2 and len(err) == 1 and "--clock-offset-ms" in err[0], err


def test_a_measured_offset_is_applied_only_when_asked():
    """The envelopes cannot tell an offset from unequal path delays (a one-host demo reads a
    few ms), so ``estimate live`` applies nothing unless given ``auto`` or ``MS``."""
    from estimator.live.config import LiveConfig
    from tpods.cli import build_parser

    args = build_parser().parse_args(["estimate", "live"])
    assert args.clock_offset_ms == "none" and LiveConfig().clock_offset_auto is False
