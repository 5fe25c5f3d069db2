"""Where a run is cut: gaps, resets and excluded ranges end a segment; lengths as asked."""

import math

import numpy as np
import pytest

from common.errors import UserError
from estimator.shooting.segments import parse_excludes, parse_segments, plan_segments


def _poses(t):
    return np.column_stack([0.01 * t, np.zeros_like(t), np.zeros_like(t)])


def test_cut_into_lengths_and_single_shooting():
    t = np.arange(0, 20.0001, 0.05)
    plan = plan_segments(t, _poses(t), 5.0)
    assert plan.n == 4
    assert plan.bounds[0, 0] == 0 and plan.bounds[-1, 1] == len(t)
    assert np.all(plan.bounds[1:, 0] == plan.bounds[:-1, 1])  # contiguous, no pose lost
    assert plan_segments(t, _poses(t), math.inf).n == 1


def test_gap_reset_and_exclude_break_segments():
    t = np.concatenate([np.arange(0, 10, 0.05), np.arange(12, 20, 0.05)])  # a 2 s gap
    p = _poses(t)
    p[300:, 0] += 1.0  # a reset: the body jumps 1 m in one interval
    plan = plan_segments(t, p, 100.0, exclude=[(4.0, 5.0, "user")])
    starts = t[plan.bounds[:, 0]]
    assert [round(s, 2) for s in starts] == [0.0, 5.05, 12.0, 17.0]
    assert [w for _, w in plan.breaks] == ["gap", "reset"]
    assert not np.any((t[plan.labels(len(t)) >= 0] >= 4.0) & (t[plan.labels(len(t)) >= 0] <= 5.0))


def test_short_pieces_dropped_and_counted():
    t = np.arange(0, 10, 0.05)
    plan = plan_segments(t, _poses(t), 5.0, exclude=[(0.11, 9.0, "x")])
    assert plan.n == 1 and plan.dropped == 1  # 0..0.1 s (3 poses) left out, 9.05..9.95 kept
    with pytest.raises(UserError, match="no stretch"):
        plan_segments(t, _poses(t), 5.0, exclude=[(0.11, 9.9, "x")])


def test_parse():
    assert parse_segments("5s") == 5.0 and parse_segments("2.5") == 2.5
    assert parse_segments("none") == math.inf and parse_segments("auto") is None
    with pytest.raises(UserError, match="positive"):
        parse_segments("-1s")
    with pytest.raises(UserError, match="length in seconds"):
        parse_segments("five")
    assert parse_excludes(["30:42.5"]) == [(30.0, 42.5)]
    with pytest.raises(UserError, match="after T0"):
        parse_excludes(["5:1"])
