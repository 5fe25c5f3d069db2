"""The bridge bench's run-queue wait of a thread (``/proc/thread-self/schedstat``)."""

import sys

import pytest

from benchmarks.bench_mocap import run_delay_s


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc is Linux's")
def test_run_delay_is_seconds_and_never_goes_back():
    a = run_delay_s()
    sum(range(200_000))
    b = run_delay_s()
    assert a is not None and b is not None and 0.0 <= a <= b
