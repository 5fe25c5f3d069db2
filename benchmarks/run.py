"""``make bench``: the performance suite.

Every case is a module ``benchmarks/bench_*.py`` with a function ``run() -> list[dict]``.
Each row holds at least ``case``, ``metric``, ``value``, ``reference``,
``ratio`` (value relative to the reference measured in the same run; > 1 means
ours is better) and ``target`` (a human-readable goal) and ``ok`` (bool or None).
Results print as a table and are written as JSON with the machine noted.

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


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="runs/bench.json")
    ap.add_argument("-k", default="", help="run only cases whose module name contains this")
    ap.add_argument("--one", help=argparse.SUPPRESS)   # internal: run one case in this process
    ap.add_argument("--rows", help=argparse.SUPPRESS)  # internal: where --one writes its rows
    args = ap.parse_args(argv)
    if args.one:
        return _one(args.one, args.rows)
    here = Path(__file__).parent
    mods = sorted(p.stem for p in here.glob("bench_*.py") if args.k in p.stem)
    rows: list[dict] = []
    failed = []
    for name in mods:
        print(f"running {name} ...", flush=True)
        try:
            rows.extend(_run_isolated(name))
        except Exception:  # report and go on with the other cases
            traceback.print_exc()
            failed.append(name)
    m = machine()
    print(f"\nmachine: {m['platform']}, {m['cpus']} cpus, python {m['python']}")
    hdr = f"{'case':<28} {'metric':<34} {'value':>12} {'reference':>12} {'ratio':>8}  ok  target"
    print(hdr)
    print("-" * len(hdr))
    for r in rows:
        ok = {True: "yes", False: "NO", None: "-"}[r.get("ok")]
        print(f"{r['case']:<28} {r['metric']:<34} {r['value']:>12.4g} {r['reference']:>12.4g} "
              f"{r['ratio']:>8.3g}  {ok:<3} {r.get('target', '')}")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"machine": m, "results": rows, "failed": failed}, indent=2) + "\n")
    print(f"\nresults written to {out}")
    return 1 if failed or any(r.get("ok") is False for r in rows) else 0


if __name__ == "__main__":
    sys.exit(main())
