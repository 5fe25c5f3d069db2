"""The noisy-host rule (benchmarks/verdict.py) and which cases make bench runs
(benchmarks/run.py), on given rows."""

import pytest

from benchmarks.run import LONG_CASES, select_cases
from benchmarks.verdict import (
    NO,
    NOISY,
    NOT_JUDGED,
    RULE,
    YES,
    Rule,
    exit_status,
    explain,
    fastest_probe_ms,
    judge,
    noisy_reasons,
    slow_reasons,
    verdict,
)

QUIET = {"steal_pct": 0.1, "others_cpu_pct": 3.0, "iowait_pct": 0.2, "probe_change_pct": 5.0}


def _row(ok, timed=True, host=QUIET, **kw):
    return {"case": "c", "metric": "m", "ok": ok, "timed": timed, "host": dict(host), **kw}


def test_quiet_host_has_no_reasons():
    assert noisy_reasons(QUIET) == []
    assert noisy_reasons(None) == []
    assert noisy_reasons({}) == []


@pytest.mark.parametrize("key, value", [("steal_pct", 0.5), ("others_cpu_pct", 10.0),
                                        ("iowait_pct", 5.0), ("probe_change_pct", 20.0)])
def test_each_threshold_alone_makes_the_host_noisy(key, value):
    assert noisy_reasons({**QUIET, key: value * 0.99}) == []
    (reason,) = noisy_reasons({**QUIET, key: value})
    assert f">= {value:g} %" in reason


def test_unmeasured_figures_count_as_quiet():
    assert noisy_reasons({k: None for k in QUIET}) == []


def test_thresholds_of_the_rule():
    assert (RULE.steal_pct, RULE.others_cpu_pct, RULE.iowait_pct, RULE.probe_change_pct,
            RULE.slow_probe_pct) == (0.5, 10.0, 5.0, 20.0, 10.0)
    assert "steal >= 0.5 %" in RULE.describe()
    assert RULE.to_dict()["others_cpu_pct"] == 10.0


def test_verdicts():
    noisy = {**QUIET, "others_cpu_pct": 60.0}
    assert verdict(_row(True, host=noisy)) == YES          # a pass on a noisy host is a pass
    assert verdict(_row(None, host=noisy)) == NOT_JUDGED
    assert verdict(_row(False)) == NO                      # missed on a quiet host
    assert verdict(_row(False, host=noisy)) == NOISY
    assert verdict(_row(False, timed=False, host=noisy)) == NO   # accuracy rows are never excused
    assert verdict(_row(False, host=noisy, ok_untimed=False)) == NO
    assert verdict(_row(False, host=noisy, ok_untimed=True)) == NOISY
    assert verdict({"ok": False}) == NO


def test_a_stricter_rule():
    strict = Rule(others_cpu_pct=80.0)
    assert verdict(_row(False, host={**QUIET, "others_cpu_pct": 60.0}), strict) == NO


def test_judge_gives_rows_their_case_window_and_a_verdict():
    rows = [{"case": "a", "metric": "m", "ok": False, "timed": True, "module": "bench_x"},
            _row(False, module="bench_x"),
            {"case": "b", "metric": "m", "ok": False, "module": "bench_y"}]
    case_hosts = {"bench_x": {**QUIET, "steal_pct": 3.0}, "bench_y": QUIET}
    out = judge(rows, case_hosts)
    assert out[0]["host"]["window"] == "case" and out[0]["verdict"] == NOISY
    assert out[0]["noisy"] == ["steal 3 % >= 0.5 %"]
    assert out[1]["host"] == QUIET and out[1]["verdict"] == NO  # its own window wins
    assert out[2]["verdict"] == NO and "noisy" not in out[2]
    assert "verdict" not in rows[0]                            # inputs untouched
    assert explain(out[0]) == "steal 3 % >= 0.5 %"
    assert explain(out[1]) == "host quiet"
    assert explain(out[2]) == "not a timing row"


def test_exit_status_fails_on_no_and_crashes_only():
    assert exit_status([{"verdict": YES}, {"verdict": NOISY}, {"verdict": NOT_JUDGED}], []) == 0
    assert exit_status([{"verdict": YES}, {"verdict": NO}], []) == 1
    assert exit_status([{"verdict": YES}], ["bench_x"]) == 1


def test_long_cases_are_left_to_bench_long():
    names = ["bench_a", "bench_coverage", "bench_sweep", "bench_z"]
    assert set(LONG_CASES) >= {"bench_coverage", "bench_sweep"}
    assert select_cases(names) == ["bench_a", "bench_z"]
    assert select_cases(names, long=True) == ["bench_coverage", "bench_sweep"]
    assert select_cases(names, k="cov") == ["bench_coverage"]   # -k reaches every case
    assert select_cases(names, k="bench_") == sorted(names)
    assert select_cases(names + ["bench_a_long"], k="bench_a") == ["bench_a"]  # exact name


def test_every_long_case_exists():
    from pathlib import Path

    import benchmarks

    here = Path(benchmarks.__file__).parent
    assert all((here / f"{name}.py").exists() for name in LONG_CASES)


def test_table_shows_the_verdict_and_unmeasured_host_figures(capsys):
    from benchmarks.run import print_table

    rows = judge([_row(False, host={**QUIET, "others_cpu_pct": 55.0}),
                  _row(True, host={"steal_pct": None, "others_cpu_pct": None}),
                  {"case": "a very long case name that is wider than the column", "metric": "m",
                   "value": 1.0, "reference": 1.0, "ratio": 1.0, "ok": None}])
    for r in rows[:2]:
        r.update(value=2.0, reference=1.0, ratio=0.5)
    print_table(rows)
    out = capsys.readouterr().out.splitlines()
    assert "verdict" in out[0] and "other%" in out[0]
    assert "noisy host" in out[2] and " 55 " in out[2]
    assert "yes" in out[3] and "n/a" in out[3]
    assert out[4].startswith("a very long case name that is wider than the column m")


# the EKF row of this session's `make bench` (runs/bench.json, 2026-11-27): 1.87e4 updates/s
# against >= 2e4, its probes 3.716 and 3.88 ms, the run's fastest probe 3.245 ms
EKF_ROW = {"case": "ekf single 120 Hz", "metric": "pose updates per s", "value": 18703.9,
           "ok": False, "timed": True, "limit": 20000.0, "better": "higher",
           "host": {**QUIET, "probe_before_ms": 3.716, "probe_after_ms": 3.88}}


def test_a_row_missed_on_a_slow_host_is_excused_by_the_slowdown_only():
    (reason,) = slow_reasons(EKF_ROW, 3.245)
    assert "probe 15 % slower" in reason and "2.14e+04 at that speed" in reason
    # a regression larger than the slowdown is still a miss
    assert slow_reasons({**EKF_ROW, "value": 15000.0}, 3.245) == []
    # a host within 10 % of the run's fastest excuses nothing
    assert slow_reasons(EKF_ROW, 3.716 / 1.09) == []
    # rows that do not state their limit as numbers are never excused this way
    assert slow_reasons({k: v for k, v in EKF_ROW.items() if k != "limit"}, 3.245) == []
    assert slow_reasons({**EKF_ROW, "better": "faster"}, 3.245) == []
    assert slow_reasons(EKF_ROW, None) == []


def test_a_time_row_scales_the_other_way():
    row = {**EKF_ROW, "value": 2.2, "limit": 2.0, "better": "lower",
           "host": {**QUIET, "probe_before_ms": 4.0, "probe_after_ms": 4.2}}
    (reason,) = slow_reasons(row, 3.2)  # 25 % slower: 2.2 s is 1.76 s at the fastest speed
    assert "1.76 at that speed" in reason
    assert slow_reasons({**row, "value": 2.6}, 3.2) == []  # 2.08 s: still over 2 s


def test_judge_excuses_a_slow_host_against_the_fastest_probe_of_the_run():
    fast_case = {**QUIET, "probe_before_ms": 3.245, "probe_after_ms": 3.3}
    rows = judge([dict(EKF_ROW), {**EKF_ROW, "value": 15000.0, "case": "regressed"},
                  {**EKF_ROW, "ok": True, "case": "passed"}], {"bench_x": fast_case})
    assert [r["verdict"] for r in rows] == [NOISY, NO, YES]
    assert "slower than the run's fastest" in explain(rows[0])
    assert rows[2]["noisy"] == []  # a pass is never given reasons
    assert fastest_probe_ms([None, {}, fast_case, EKF_ROW["host"]]) == 3.245
    assert fastest_probe_ms([None, {"probe_before_ms": None}]) is None
    # without any faster probe in the run the row's miss stands
    assert judge([dict(EKF_ROW)])[0]["verdict"] == NO
