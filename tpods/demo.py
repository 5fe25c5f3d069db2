"""``tpods demo``: the main job on emulated devices (no hardware needed).

For now: simulate the paper's 120 s phase-shifted-sine run and summarise it. The
later issues grow this into the full lab day (bench, bifilar, live estimation).
"""

from __future__ import annotations

import argparse
import datetime as _dt
from pathlib import Path


def register(sub) -> None:
    p = sub.add_parser("demo", help="run the main job on emulated devices",
                       description="Run the lab day on emulated devices and write a report under runs/.")
    p.add_argument("--out", default=None, help="output folder (default runs/demo-<timestamp>)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.set_defaults(func=cmd_demo)


def cmd_demo(args: argparse.Namespace) -> int:
    from estimator.inputs import phase_sine
    from estimator.model import PlantParams
    from estimator.sim import SimConfig, simulate, summary_lines, write_sim_run

    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    out = Path(args.out) if args.out else Path("runs") / f"demo-{stamp}"
    cmd_t, duty = phase_sine(120.0, 50.0)
    res = simulate(cmd_t, duty, PlantParams(2.268, 3.78e-3), config=SimConfig(seed=args.seed))
    run_dir = write_sim_run(res, out / "sim-run", "phase-sine")
    print(f"simulated run written to {run_dir}")
    for line in summary_lines(res):
        print("  " + line)
    return 0
