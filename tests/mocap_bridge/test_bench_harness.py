"""The mocap bench's host-interference gate (pure helpers of benchmarks/bench_mocap.py)."""

import pytest

from benchmarks.bench_mocap import cpu_ticks, steal_pct


def test_steal_share_of_all_cpu_time():
    # 3 ticks stolen out of 600 ticks of both CPUs: 0.5 %
    assert steal_pct((10, 1000), (13, 1600)) == 0.5
    assert steal_pct((10, 1000), (10, 1600)) == 0.0


def test_steal_unmeasurable_counts_as_zero():
    assert steal_pct(None, (1, 2)) == 0.0
    assert steal_pct((1, 2), None) == 0.0
    assert steal_pct((5, 100), (5, 100)) == 0.0  # no time passed


def test_cpu_ticks_reads_proc_stat_on_linux():
    t = cpu_ticks()
    if t is None:
        pytest.skip("no /proc/stat here (the gate then treats steal as 0)")
    steal, total = t
    assert 0 <= steal <= total and total > 0
