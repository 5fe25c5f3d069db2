import math

import numpy as np

from estimator.live.align import LiveAligner


def test_pose_waits_for_its_command_then_releases_in_order():
    a = LiveAligner(max_wait_s=0.05)
    a.push_command(0.0, [50, 50, 50, 50])
    a.push_pose(1, 0.010, 0, 0, 0, arrival=0.011)
    a.push_pose(3, 0.030, 0, 0, 0, arrival=0.031)
    a.push_pose(2, 0.020, 0, 0, 0, arrival=0.032)  # out of order, still pending: accepted
    assert a.pop_ready(now=0.033) == []  # no command stamped >= 0.01 yet, not timed out
    a.push_command(0.025, [10, 0, 0, 0])
    out = a.pop_ready(now=0.034)
    assert [p.frame for p in out] == [1, 2]  # frame 3 (t=0.03) still waits
    out = a.pop_ready(now=0.031 + 0.051)
    assert [p.frame for p in out] == [3] and a.stats.released_by_timeout == 1
    assert a.stats.poses_out == 3


def test_bad_samples_are_counted_and_skipped():
    a = LiveAligner()
    a.push_command(0.0, [0, 0, 0, 0])
    assert not a.push_pose(1, 0.1, 0, 0, 0, occluded=True)
    assert not a.push_pose(2, 0.1, math.nan, 0, 0)
    assert not a.push_pose(3, math.inf, 0, 0, 0)
    assert a.push_pose(4, 0.2, 0, 0, 0)
    assert not a.push_pose(4, 0.2, 0, 0, 0)  # repeated frame
    a.push_command(0.3, [1, 1, 1, 1])
    assert [p.frame for p in a.pop_ready(0.3)] == [4]
    assert not a.push_pose(5, 0.15, 0, 0, 0)  # older than what was released
    assert not a.push_command(0.1, [5, 5, 5, 5])  # would rewrite the past
    assert not a.push_command(0.4, [5, 5, 5])  # wrong channel count
    assert not a.push_command(0.4, [500, 5, 5, 5])  # duty out of range
    assert not a.push_command("x", [5, 5, 5, 5])
    s = a.stats
    assert (s.occluded, s.non_finite, s.duplicates, s.too_old, s.cmds_late, s.cmds_bad) == (1, 2, 1, 1, 1, 3)


def test_poses_before_the_first_command_are_dropped():
    a = LiveAligner(max_wait_s=0.05)
    a.push_pose(1, 0.0, 0, 0, 0, arrival=0.0)
    assert a.pop_ready(0.01) == []
    a.push_command(0.005, [0, 0, 0, 0])
    a.push_pose(2, 0.01, 0, 0, 0, arrival=0.01)
    a.push_command(0.02, [0, 0, 0, 0])
    assert [p.frame for p in a.pop_ready(0.02)] == [2]
    assert a.stats.before_first_cmd == 1


def test_commands_between_restamps_the_held_command():
    a = LiveAligner()
    for t, d in [(0.0, 10), (0.02, 20), (0.04, 30), (0.06, 40)]:
        a.push_command(t, [d] * 4)
    t, d = a.commands_between(0.03, 0.06)
    np.testing.assert_allclose(t, [0.03, 0.04, 0.06])
    np.testing.assert_allclose(d[:, 0], [20, 30, 40])
    a.push_command(0.04, [33] * 4)  # same stamp: the later message wins
    assert a.commands()[1][2, 0] == 33
