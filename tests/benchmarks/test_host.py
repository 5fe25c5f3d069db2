"""The bench's host readings (benchmarks/host.py): /proc parsing and the figures of a window,
on given numbers (no timing here)."""

import pytest

from benchmarks.host import (
    CpuTicks,
    LoadAvg,
    Snapshot,
    host_conditions,
    parse_loadavg,
    parse_proc_stat,
    probe_change_pct,
)

PROC_STAT = """cpu  54360 271 2735 25278 123 0 169 78 0 0
cpu0 27000 100 1400 12600 60 0 90 40 0 0
cpu1 27360 171 1335 12678 63 0 79 38 0 0
intr 123456 0 0
ctxt 98765
"""


def test_proc_stat_aggregate_line():
    t = parse_proc_stat(PROC_STAT)
    assert t == CpuTicks(54360, 271, 2735, 25278, 123, 0, 169, 78)
    assert t.total == 54360 + 271 + 2735 + 25278 + 123 + 0 + 169 + 78
    assert t.busy == 54360 + 271 + 2735


def test_proc_stat_guest_columns_are_not_counted_twice():
    # guest time is already inside user: the 9th and 10th columns are left out of total
    t = parse_proc_stat("cpu 10 0 0 90 0 0 0 0 500 500\n")
    assert t.total == 100


@pytest.mark.parametrize("text", ["", "cpu0 1 2 3 4 5 6 7 8\n", "cpu 1 2 3 4 5 6 7\n",
                                  "cpu 1 2 x 4 5 6 7 8\n"])
def test_proc_stat_without_a_usable_cpu_line(text):
    assert parse_proc_stat(text) is None


def test_loadavg():
    assert parse_loadavg("0.52 0.61 0.70 2/345 6789\n") == LoadAvg(0.52, 0.61, 0.70, 2, 345)
    assert parse_loadavg("garbage") is None
    assert parse_loadavg("1 2 3 4 5") is None


def _snap(t, own, ticks, load1=1.0, probe=None):
    return Snapshot(t, own, CpuTicks(*ticks), LoadAvg(load1, 0, 0, 1, 100), probe)


def test_window_figures_are_shares_of_all_cpus_time():
    # 2 CPUs, 10 s at 100 ticks/s: 2000 ticks. The bench used 6 CPU s (600 ticks); all
    # processes 900 ticks of user+system: others 300 (15 %). Steal 20 (1 %), iowait 40 (2 %).
    a = _snap(100.0, 50.0, (1000, 0, 500, 5000, 100, 0, 0, 10), load1=0.5, probe=10.0)
    b = _snap(110.0, 56.0, (1800, 0, 600, 6040, 140, 0, 0, 30), load1=2.5, probe=13.0)
    h = host_conditions(a, b, hz=100.0)
    assert h["seconds"] == 10.0
    assert h["own_cpu_s"] == 6.0
    assert h["steal_pct"] == 1.0
    assert h["iowait_pct"] == 2.0
    assert h["others_cpu_pct"] == 15.0
    assert h["own_cpu_pct"] == 30.0
    assert h["idle_pct"] == 52.0
    assert (h["load1_start"], h["load1_end"]) == (0.5, 2.5)
    assert (h["probe_before_ms"], h["probe_after_ms"], h["probe_change_pct"]) == (10.0, 13.0, 30.0)


def test_others_never_negative():
    # tick sampling can credit the bench with more than the busy ticks seen: clipped at 0
    a = _snap(0.0, 0.0, (0, 0, 0, 0, 0, 0, 0, 0))
    b = _snap(1.0, 1.5, (100, 0, 0, 100, 0, 0, 0, 0))
    h = host_conditions(a, b, hz=100.0)
    assert h["others_cpu_pct"] == 0.0
    assert h["own_cpu_pct"] == 75.0


def test_unmeasurable_figures_are_none():
    a = Snapshot(0.0, 0.0, None, None, None)
    b = Snapshot(2.0, 1.0, None, None, None)
    h = host_conditions(a, b)
    assert h["seconds"] == 2.0
    assert all(h[k] is None for k in ("steal_pct", "iowait_pct", "others_cpu_pct", "own_cpu_pct",
                                      "idle_pct", "load1_start", "load1_end", "probe_change_pct"))
    # no time passed on the tick counter: nothing to divide by
    t = (5, 0, 0, 5, 0, 0, 0, 0)
    assert host_conditions(_snap(0, 0, t), _snap(0, 0, t))["steal_pct"] is None


def test_probe_change_relative_to_the_faster():
    assert probe_change_pct(10.0, 12.0) == 20.0
    assert probe_change_pct(12.0, 10.0) == 20.0
    assert probe_change_pct(10.0, 10.0) == 0.0
    assert probe_change_pct(None, 10.0) is None
    assert probe_change_pct(0.0, 10.0) is None
