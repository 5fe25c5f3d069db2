"""The lab clock: scaled time shared by processes with the same origin."""

from __future__ import annotations

import time

import pytest

from common.errors import UserError
from tpods.clock import LabClock


def test_scaled_clock_is_consistent_and_invertible():
    origin = time.time() - 10.0
    a, b = LabClock(5.0, origin), LabClock(5.0, origin)
    ta, tb = a.now(), b.now()
    assert abs(ta - tb) < 5 * 0.01  # two "processes", one lab time
    assert ta - origin == pytest.approx(5 * (time.time() - origin), abs=0.1)
    assert a.to_host(a.to_lab(1.7e9)) == pytest.approx(1.7e9)
    assert LabClock().now() == pytest.approx(time.time(), abs=0.01)  # scale 1: the host clock


def test_sleep_until_runs_scaled_and_stops_on_request():
    import threading

    c = LabClock(4.0, time.time())
    t0 = time.monotonic()
    assert c.sleep_until(c.now() + 0.4)  # 0.4 lab s = 0.1 real s
    assert 0.09 < time.monotonic() - t0 < 0.3
    stop = threading.Event()
    stop.set()
    assert not c.sleep_until(c.now() + 100.0, stop)


def test_bad_scale_is_a_user_error():
    for s in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(UserError):
            LabClock(s)
