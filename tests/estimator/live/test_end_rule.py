"""``run_live(exit_on_end=True)``: when the run ends after the player's ``end`` command.
Every pose of the grace span is used however late the host delivers it: the rule is the
poses' lab stamps (a mocap that keeps streaming) or an idle stream (a replay that stops),
never a fixed host delay after the ``end`` (loopback peers, no multicast)."""

from __future__ import annotations

import threading
import time

import zenoh

from common.thrust_table import ThrustTable
from common.wire import encode_command, encode_pose
from estimator.live.runtime import LiveConfig, LiveEstimator, run_live
from tests.support.net import matching, wait_for

T0 = 1000.0  # lab time of the first command, s


def _pose(frame: int, t: float) -> bytes:
    return encode_pose("tpods1", frame, t, t, (0.001 * frame, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0))


def _start(zenoh_pair, grace_s: float):
    pub, sub, _ = zenoh_pair
    est = LiveEstimator(ThrustTable.default(), LiveConfig(publish_rate_hz=0))
    out: dict = {}
    th = threading.Thread(target=lambda: out.update(res=run_live(sub, est, exit_on_end=True,
                                                                 end_grace_s=grace_s)))
    th.start()
    block = zenoh.CongestionControl.BLOCK
    cmd = pub.declare_publisher("tpods/tpods1/cmd", congestion_control=block)
    pose = pub.declare_publisher("tpods/mocap/tpods1/pose", congestion_control=block)
    assert wait_for(lambda: matching(cmd) and matching(pose), 10.0)
    cmd.put(encode_command("tpods1", 1, T0, (0.0, 0.0, 0.0, 0.0)))
    for k in range(1, 101):  # 1 s at 100 Hz, then the end command
        pose.put(_pose(k, T0 + 0.01 * k))
    cmd.put(encode_command("tpods1", 2, T0 + 1.0, (0.0, 0.0, 0.0, 0.0), "end"))
    assert wait_for(lambda: est.end_seen_t is not None, 10.0)
    return est, th, pose, out


def test_a_stream_that_pauses_after_the_end_loses_no_pose(zenoh_pair):
    """Two poses after the end, each 0.4 s of host time after the one before: more than half
    the grace (0.6 s) in all, which a fixed host delay after the end would have cut."""
    est, th, pose, out = _start(zenoh_pair, 0.6)
    for k in (101, 102):
        time.sleep(0.4)
        pose.put(_pose(k, T0 + 0.01 * k))
    th.join(10)
    assert not th.is_alive()
    assert est.counters.poses_rx == 102 and out["res"].after_end == 0


def test_a_stream_that_goes_on_ends_at_the_span_in_lab_time(zenoh_pair):
    """Poses keep coming (twice lab speed, for 3 s of host time: the idle rule never fires):
    the run uses exactly the poses stamped up to end + 1 s (``end_span_s``) and ends at the
    first one stamped later, which it does not use."""
    est, th, pose, out = _start(zenoh_pair, 0.5)
    t_end_lab = T0 + 1.0
    sent = 100
    stamped_within = 100
    t_stop = time.monotonic() + 3.0
    while th.is_alive() and time.monotonic() < t_stop:
        sent += 1
        t = T0 + 0.01 * sent
        pose.put(_pose(sent, t))
        stamped_within += t <= t_end_lab + 1.0
        time.sleep(0.005)
    th.join(10)
    assert not th.is_alive() and time.monotonic() < t_stop, "the run waited for the stream to stop"
    assert est.counters.poses_rx == stamped_within
    assert out["res"].after_end >= 1 and est.counters.poses_rx + out["res"].after_end <= sent
