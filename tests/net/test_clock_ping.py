"""The round-trip clock measurement: on arrays (NTP-style, the least-queued exchanges
kept) and across two Zenoh sessions on loopback (an explicit endpoint, no multicast
scouting), the answering side's clock 20 ms ahead (injected)."""

from __future__ import annotations

import time

import numpy as np

from common.clock_ping import clock_key, ping_clock, ping_estimate, serve_clock
from common.zenoh_net import open_session
from tests.support.net import free_port

OFFSET_S = 0.020


def test_ping_estimate_keeps_the_shortest_round_trips():
    """Asymmetric queueing on the longer exchanges biases them; the shortest quarter gives
    the offset within its half round trip, and malformed exchanges are skipped."""
    rng = np.random.default_rng(1)
    samples = []
    for k in range(40):
        t0 = 10.0 + 0.1 * k
        up, down = 2e-4 + rng.exponential(2e-3), 2e-4 + rng.exponential(2e-4)
        samples.append((t0, t0 + up + OFFSET_S, t0 + up + down))
    samples += [(1.0, 2.0, 0.5), (float("nan"), 1.0, 1.0)]  # negative, non-finite round trip
    e = ping_estimate(samples)
    assert e is not None and e.answered == 40 and e.kept == 10
    assert abs(e.offset_s - OFFSET_S) < 0.5 * e.rtt_min_s + 3 * e.sigma_s < 2e-3, e
    assert ping_estimate(samples[:2]) is None


def test_ping_over_zenoh_on_loopback_measures_an_injected_offset():
    """The player's side answers on <prefix>/<body>/clock with its clock 20 ms ahead; the
    estimator's side measures +20 ms within 2 ms, and nothing when nobody answers."""
    ep = f"tcp/127.0.0.1:{free_port()}"
    a = open_session(listen=[ep], no_multicast=True)
    b = open_session(connect=[ep], no_multicast=True)
    try:
        key = clock_key("tpods1")
        q = serve_clock(a, key, clock=lambda: time.time() + OFFSET_S)
        e = None
        for _ in range(50):  # the route takes a moment to be known
            e = ping_clock(b, key, n=20, timeout_s=0.5)
            if e is not None:
                break
            time.sleep(0.1)
        assert e is not None and abs(e.offset_s - OFFSET_S) < 2e-3, e
        assert e.sigma_s < 2e-3 and e.rtt_min_s < 0.05, e
        q.undeclare()
        assert ping_clock(b, clock_key("nobody"), n=3, timeout_s=0.2) is None
    finally:
        b.close()
        a.close()
