"""The fault table of docs/live.md from a run of the namespace fault tests:
``python -m tests.support.fault_table LAB-FAULTS.jsonl`` prints it as Markdown.

The tests (tests/net/test_lab_faults*.py) append one JSON line each to
``$TPODS_LAB_REPORT_DIR/lab-faults.jsonl`` (default: the pytest run's temporary folder)."""

from __future__ import annotations

import json
import sys
from pathlib import Path


def _z(v) -> str:
    return "-" if v is None else f"{v:+.1f}"


def row(d: dict) -> str:
    """One table row: fault, what was held, recovery, what was lost, the estimate."""
    gaps = d.get("gaps") or []
    lost_p = sum(g["missing"] for g in gaps if g["stream"] == "poses")
    lost_c = sum(g["missing"] for g in gaps if g["stream"] == "commands")
    named = len(gaps)
    late = max((g["silent_s"] for g in gaps if g["missing"] == 0), default=0.0)
    if "recovery_s" in d:
        rec = f"first pose {d['recovery_s']:.2f} s after {d.get('recovery_from', 'the heal')}"
        if "filter_back_s" in d:
            rec += f"; filter sigma back {d['filter_back_s']:.2f} s after the gap"
    elif "valves_closed_after_s" in d:
        rec = f"valves closed {d['valves_closed_after_s'] * 1e3:.0f} ms after the cut"
    elif "restart_gap_s" in d:
        rec = f"new estimator's first live pose {d['restart_gap_s']:.2f} s after the old one's last"
    else:
        rec = "-"
    lost = (f"{lost_p} poses, {lost_c} commands" if lost_p or lost_c else "nothing")
    names = f"{named} gap(s) named" + (f", longest pause {late:.2f} s" if late > 0 else "")
    return (f"| {d['fault']} | {d['held']} | {rec} | {lost} | {names} | "
            f"{_z(d.get('mass_z'))} / {_z(d.get('izz_z'))} |")


def table(lines: list[dict]) -> str:
    head = ("| fault | held | recovery | lost | named by the estimator | m / Izz error (sigma) |\n"
            "|---|---|---|---|---|---|")
    return "\n".join([head, *(row(d) for d in lines)])


def main(argv: list[str] | None = None) -> int:
    path = Path((argv or sys.argv[1:])[0])
    lines = [json.loads(x) for x in path.read_text().splitlines() if x.strip()]
    print(table(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
