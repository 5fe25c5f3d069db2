"""Sub-commands of the estimator package: ``tpods sim`` (and the estimators as they land)."""

from __future__ import annotations

import argparse
import sys

from common.argtypes import float_list, fraction, nonneg_float, positive_float
from common.outputs import ResultFolder, add_force
from tpods.cli.options import (
    add_cmd_rate,
    add_input_choice,
    add_pose_rate,
    add_random_seed,
    add_sine_amplitude,
    add_structure_or_vehicle,
    add_thrust_table,
)
from tpods.cli.parser import command, group


def register(sub) -> None:
    from tpods.cli.design import register as register_design
    from tpods.cli.estimate_batch import register as register_batch
    from tpods.cli.estimate_ekf import register as register_ekf
    from tpods.cli.estimate_live import register as register_live
    from tpods.cli.estimate_realism import register as register_realism  # report realism

    register_sim(sub)
    est = group(sub, "estimate", "estimate mass and Izz from a run (batch, filters, bounds)")
    rep = group(sub, "report", "generate the paper-comparison reports")
    register_batch(sub, est, rep)
    register_design(sub)
    register_ekf(sub, est, rep)
    register_realism(sub, est, rep)
    register_live(est)


def register_sim(sub) -> None:
    p = command(sub, "sim", cmd_sim, help="simulate a TPODS run and write a run folder")
    add_input_choice(p)
    p.add_argument("--duration", type=positive_float, default=None,
                   help="seconds (default 120; a commands.csv input: its whole length)")
    p.add_argument("--mass", type=positive_float, default=None,
                   help="kg (default: the structure's [body] mass_kg, else 2.268)")
    p.add_argument("--izz", type=positive_float, default=None,
                   help="kg m^2 about the centre of mass (default: the structure's [body] "
                        "izz_kgm2, else 3.78e-3)")
    add_structure_or_vehicle(p, "structure.toml: simulate several modules on one rigid body (copied "
                        "into the run folder as given: its [body] values are known values or "
                        "priors for tpods estimate; the truth goes to run.json)")
    p.add_argument("--com", type=float_list(2), default=None, metavar="X,Y",
                   help="--structure: the true centre of mass in the tracked frame, m (default "
                        "its [body] com_m, else 0,0; a negative X as --com=-0.02,0)")
    p.add_argument("--friction", type=float_list(3), default=None, metavar="CT,CR,KB",
                   help="viscous friction N s/m, rotational friction N m s/rad, yaw bias N m s/m")
    p.add_argument("--tilt", type=float_list(2), default=None, metavar="AX,AY",
                   help="constant lab-frame disturbance acceleration, m/s^2")
    add_thrust_table(p)
    p.add_argument("--clamp", action="store_true", help="clamp duties into the table's valid range")
    add_pose_rate(p)
    add_cmd_rate(p)
    add_sine_amplitude(p)
    p.add_argument("--omega", type=positive_float, default=1.0,
                   help="phase-sine frequency, rad/s (default 1)")
    p.add_argument("--noise-pos", type=nonneg_float, default=0.01, help="position noise sigma, m")
    p.add_argument("--noise-yaw-deg", type=nonneg_float, default=1.0, help="yaw noise sigma, deg")
    p.add_argument("--drop", type=fraction, default=0.0, help="fraction of frames dropped at random")
    add_random_seed(p)
    p.add_argument("--out", required=True, help="run folder to write")
    add_force(p)


def cmd_sim(args: argparse.Namespace) -> int:
    """Simulate the planar TPODS plant under held thruster commands and write a run folder
    (commands.csv, poses.csv, truth.csv, run.json)."""
    from estimator.plant.sim_case import simulate_case

    out = ResultFolder(args.out, force=args.force, command="tpods sim")
    case = simulate_case(
        args.input, duration_s=args.duration, mass_kg=args.mass, izz_kgm2=args.izz,
        structure=args.structure, com=args.com, friction=args.friction, tilt=args.tilt,
        thrust_table=args.thrust_table, clamp=args.clamp, pose_rate_hz=args.pose_rate,
        cmd_rate_hz=args.cmd_rate, amplitude_pct=args.amplitude, omega_rad_s=args.omega,
        noise_pos_m=args.noise_pos, noise_yaw_deg=args.noise_yaw_deg, drop=args.drop,
        seed=args.seed, warn=lambda w: print(f"tpods: warning: {w}", file=sys.stderr))
    with out.writing() as d:
        case.write(d)
    print(f"wrote {out.path}")
    for line in case.lines():
        print(line)
    return 0


def check_sim_size(args: argparse.Namespace, duration_s: float, n_cmds: int | None = None) -> None:
    """:func:`estimator.plant.size_checks.check_sim_size` of the ``tpods sim`` options."""
    from estimator.plant.size_checks import check_sim_size as check

    check(duration_s, args.pose_rate, args.cmd_rate, n_cmds, duration_given=bool(args.duration),
          input_name=args.input)
