"""``make bench``: the performance suite (``make bench-long``: the cases that take minutes).

Every case is a module ``benchmarks/bench_*.py`` with a function ``run() -> list[dict]``.
Each row holds at least ``case``, ``metric``, ``value``, ``reference``,
``ratio`` (value relative to the reference measured in the same run; > 1 means
ours is better) and ``target`` (a human-readable goal) and ``ok`` (bool or None).
A row whose ``ok`` depends on wall-clock time also has ``timed`` True and ``host``: what
the host did while it ran (:mod:`benchmarks.host`); the runner adds its case's host
window to every row without one, then a ``verdict`` (yes, NO, noisy host, -) by the rule
of :mod:`benchmarks.verdict`. Results print as a table and are written as JSON with the
machine, the rule and each case's wall time noted. Exit status 1 when a case crashed or a
row is NO (missed on a quiet host); "noisy host" does not fail. Details: docs/bench.md.

Each case runs in a fresh Python process of its own (``--one NAME``), so no case measures
in the company of what an earlier one left behind (Zenoh runtimes, threads, memory).
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path

from benchmarks.host import LoadSampler, Window
from benchmarks.verdict import (
    NO,
    NOISY,
    NOT_JUDGED,
    RULE,
    YES,
    exit_status,
    explain,
    judge,
    summary,
)

LONG_CASES = {
    "bench_batch_scipy": "scipy least_squares + solve_ivp on the batch fit's problem",
    "bench_calibration": "40 bifilar trace fits (accuracy, not timing)",
    "bench_coverage": "1,200 simulated runs with drawn thrust tables",
    "bench_ekf_mc": "the EKF Monte Carlo, 500 runs x 120 s",
    "bench_mocap_capture": "8 bridge runs with --capture on and off",
    "bench_realism_mc": "a 200-run Monte Carlo of the friction+tilt model",
    "bench_session": "a full 4 x 9-step thrust characterisation (136 s planned)",
    "bench_sweep": "every estimator on 300 simulated runs",
}
"""Cases of ``make bench-long`` (``--long``), each minutes long; ``make bench`` leaves them out."""


def machine() -> dict:
    return {
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cpus": os.cpu_count(),
        "time": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }


def _one(name: str, out: str) -> int:
    """Run one case in this process and write its rows as JSON to ``out``."""
    rows = importlib.import_module(f"benchmarks.{name}").run()
    Path(out).write_text(json.dumps(rows))
    return 0


def _run_isolated(name: str) -> list[dict]:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "rows.json"
        proc = subprocess.run([sys.executable, "-m", "benchmarks.run", "--one", name, "--rows", str(out)])
        if proc.returncode != 0 or not out.exists():
            raise RuntimeError(f"{name} exited with status {proc.returncode}")
        return json.loads(out.read_text())


def select_cases(names: list[str], k: str = "", long: bool = False) -> list[str]:
    """The cases to run: with ``k``, the case named ``k`` if there is one, else every case
    whose name contains it (long or not); otherwise the long cases with ``long``, the others
    without."""
    if k:
        return [k] if k in names else sorted(n for n in names if k in n)
    return sorted(n for n in names if (n in LONG_CASES) == long)


def _fmt(x: float | None, spec: str = ".1f") -> str:
    return "n/a" if x is None else format(x, spec)


def print_table(rows: list[dict]) -> None:
    wc = max([28, *(len(r["case"]) for r in rows)])
    wm = max([34, *(len(r["metric"]) for r in rows)])
    hdr = (f"{'case':<{wc}} {'metric':<{wm}} {'value':>10} {'reference':>10} {'ratio':>7}  "
           f"{'verdict':<10} {'steal%':>6} {'other%':>6} {'iow%':>5} {'load1':>5} {'probe%':>6}  target")
    print(hdr)
    print("-" * len(hdr))
    for r in rows:
        h = r.get("host") or {}
        load = h.get("load1_max", h.get("load1_end"))
        print(f"{r['case']:<{wc}} {r['metric']:<{wm}} {r['value']:>10.4g} {r['reference']:>10.4g} "
              f"{r['ratio']:>7.3g}  {r['verdict']:<10} {_fmt(h.get('steal_pct')):>6} "
              f"{_fmt(h.get('others_cpu_pct'), '.0f'):>6} {_fmt(h.get('iowait_pct')):>5} "
              f"{_fmt(load):>5} {_fmt(h.get('probe_change_pct'), '.0f'):>6}  {r.get('target', '')}")


def _report(rows: list[dict], failed: list[str], cases: dict, wall_s: float, out: Path) -> int:
    m = machine()
    print(f"\nmachine: {m['platform']}, {m['cpus']} cpus, python {m['python']}")
    print_table(rows)
    counts = summary(rows)
    print(f"\n{counts[YES]} yes, {counts[NO]} NO, {counts[NOISY]} noisy host, "
          f"{counts[NOT_JUDGED]} not judged; {len(failed)} case(s) crashed; {wall_s:.0f} s in all")
    print(f"rule: {RULE.describe()} (host columns: the row's window, or its case's)")
    for r in rows:
        if r["verdict"] in (NO, NOISY):
            print(f"  {r['verdict']}: {r['case']} / {r['metric']} ({explain(r)})")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"machine": m, "rule": RULE.to_dict(), "wall_s": round(wall_s, 1),
                               "cases": cases, "summary": counts, "results": rows,
                               "failed": failed}, indent=2) + "\n")
    print(f"\nresults written to {out}")
    return exit_status(rows, failed)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=None, help="JSON report (default runs/bench.json, "
                                                "with --long runs/bench-long.json)")
    ap.add_argument("-k", default="", help="run only the case of this module name, or those "
                                           "whose name contains it (long cases included)")
    ap.add_argument("--long", action="store_true", help="run the long cases (make bench-long)")
    ap.add_argument("--one", help=argparse.SUPPRESS)   # internal: run one case in this process
    ap.add_argument("--rows", help=argparse.SUPPRESS)  # internal: where --one writes its rows
    args = ap.parse_args(argv)
    if args.one:
        return _one(args.one, args.rows)
    here = Path(__file__).parent
    mods = select_cases([p.stem for p in here.glob("bench_*.py")], args.k, args.long)
    rows: list[dict] = []
    failed: list[str] = []
    cases: dict[str, dict] = {}
    t_start = time.monotonic()
    for name in mods:
        print(f"running {name} ...", flush=True)
        window, sampler = Window(), LoadSampler()
        try:
            rows.extend({**r, "module": name} for r in _run_isolated(name))
        except Exception:  # report and go on with the other cases
            traceback.print_exc()
            failed.append(name)
        host = {**window.stop(), **sampler.stop()}
        cases[name] = {"wall_s": host["seconds"], "cpu_s": host["own_cpu_s"], "host": host}
        print(f"  {name}: {host['seconds']:.0f} s wall, {host['own_cpu_s']:.0f} CPU s", flush=True)
    rows = judge(rows, {n: c["host"] for n, c in cases.items()})
    out = Path(args.out or ("runs/bench-long.json" if args.long else "runs/bench.json"))
    status = _report(rows, failed, cases, time.monotonic() - t_start, out)
    if not args.k:  # a whole run (not one case): docs/bench.md from this report
        from benchmarks.page import write_page
        print(f"page written to {write_page(out.with_name('bench.json'))}")
    return status


if __name__ == "__main__":
    sys.exit(main())
