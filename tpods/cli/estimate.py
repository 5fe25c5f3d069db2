"""Sub-commands of the estimator package: ``tpods sim`` (and the estimators as they land)."""

from __future__ import annotations

import argparse
import math

from common.argtypes import float_list, fraction, nonneg_float, positive_float
from common.constants import PAPER_IZZ_KGM2, PAPER_MASS_KG
from common.outputs import ResultFolder, add_force


def register(sub) -> None:
    from tpods.cli import estimate_batch as cli_batch
    from tpods.cli import estimate_ekf as cli_ekf
    from tpods.cli import group

    register_sim(sub)
    est = group(sub, "estimate", "estimate mass and Izz from a run (batch, filters, bounds)")
    rep = group(sub, "report", "generate the paper-comparison reports")
    cli_batch.register(sub, est, rep)
    cli_ekf.register(sub, est, rep)
    from tpods.cli import estimate_realism as cli_realism  # issue 9: tpods report realism

    cli_realism.register(sub, est, rep)
    from tpods.cli import estimate_live as cli_live

    cli_live.register(est)


def register_sim(sub) -> None:
    p = sub.add_parser(
        "sim", help="simulate a TPODS run and write a run folder",
        description="Simulate the planar TPODS plant under held thruster commands and write a run "
                    "folder (commands.csv, poses.csv, truth.csv, run.json).")
    p.add_argument("--input", default="phase-sine",
                   help="phase-sine, translate-rotate or PATH/commands.csv (default phase-sine)")
    p.add_argument("--duration", type=positive_float, default=120.0, help="seconds (default 120)")
    p.add_argument("--mass", type=positive_float, default=PAPER_MASS_KG, help="kg (default 2.268)")
    p.add_argument("--izz", type=positive_float, default=PAPER_IZZ_KGM2, help="kg m^2 (default 3.78e-3)")
    p.add_argument("--friction", type=float_list(3), default=None, metavar="CT,CR,KB",
                   help="viscous friction N s/m, rotational friction N m s/rad, yaw bias N m s/m")
    p.add_argument("--tilt", type=float_list(2), default=None, metavar="AX,AY",
                   help="constant lab-frame disturbance acceleration, m/s^2")
    p.add_argument("--thrust-table", default=None, metavar="F",
                   help="thrust table TOML (default: the paper's Table 2)")
    p.add_argument("--clamp", action="store_true", help="clamp duties into the table's valid range")
    p.add_argument("--pose-rate", type=positive_float, default=120.0, help="Hz (default 120)")
    p.add_argument("--cmd-rate", type=positive_float, default=50.0, help="Hz (default 50)")
    p.add_argument("--amplitude", type=nonneg_float, default=20.0,
                   help="phase-sine amplitude, duty percent (default 20)")
    p.add_argument("--omega", type=positive_float, default=1.0,
                   help="phase-sine frequency, rad/s (default 1)")
    p.add_argument("--noise-pos", type=nonneg_float, default=0.01, help="position noise sigma, m")
    p.add_argument("--noise-yaw-deg", type=nonneg_float, default=1.0, help="yaw noise sigma, deg")
    p.add_argument("--drop", type=fraction, default=0.0, help="fraction of frames dropped at random")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--out", required=True, help="run folder to write")
    add_force(p)
    p.set_defaults(func=cmd_sim)


def cmd_sim(args: argparse.Namespace) -> int:
    from common.thrust_table import load_thrust_table
    from estimator.plant.inputs import make_input
    from estimator.plant.model import PlantParams
    from estimator.plant.sim import SimConfig, simulate, summary_lines, write_sim_run

    out = ResultFolder(args.out, force=args.force)
    table = load_thrust_table(args.thrust_table)
    cmd_t, duty = make_input(args.input, args.duration, args.cmd_rate, args.amplitude, args.omega)
    ct, cr, kb = args.friction or (0.0, 0.0, 0.0)
    ax, ay = args.tilt or (0.0, 0.0)
    params = PlantParams(args.mass, args.izz, ct=ct, cr=cr, kb=kb, ax=ax, ay=ay)
    cfg = SimConfig(pose_rate_hz=args.pose_rate, noise_pos_m=args.noise_pos,
                    noise_yaw_rad=math.radians(args.noise_yaw_deg), drop=args.drop,
                    seed=args.seed, clamp=args.clamp)
    res = simulate(cmd_t, duty, params, table, cfg)
    with out.writing() as d:
        write_sim_run(res, d, args.input, args.thrust_table or "built-in Table 2")
    print(f"wrote {out.path}")
    for line in summary_lines(res):
        print("  " + line)
    return 0
