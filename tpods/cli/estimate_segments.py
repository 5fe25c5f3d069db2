"""``tpods estimate batch RUN --segments LEN|auto`` and ``--thruster-health``: a whole run
fitted by multiple shooting; a thin shell that parses the options, calls the use case
(:func:`estimator.reports.segments_report.fit_run_by_segments`) and prints or writes what it
returns."""

from __future__ import annotations

import argparse
import math

from tpods.cli.estimate_output import report


def add_options(p: argparse.ArgumentParser) -> None:
    """The segment fit's options of ``tpods estimate batch``."""
    p.add_argument("--segments", default=None, metavar="LEN|auto|none",
                   help="fit the run as shooting segments, each from its own initial state with "
                        "the physical parameters shared: a length (5s), auto (chosen from the "
                        "data) or none (single shooting, the default); for whole real runs")
    p.add_argument("--exclude", action="append", default=None, metavar="T0:T1",
                   help="with --segments: leave out the poses in T0..T1 (run seconds; repeatable)")
    p.add_argument("--thruster-health", action="store_true",
                   help="each thruster's efficiency (relative to the others; absolute with "
                        "--fixed mass=KG) and a verdict: ok, weak, dead, reversed, stuck-open "
                        "(fits by segments; --segments auto unless given)")
    p.add_argument("--out-vehicle", default=None, metavar="NEW.toml",
                   help="with --thruster-health: write the vehicle file with the verdicts "
                        "applied (a dead thruster gives no thrust in every estimator)")


def wanted(args: argparse.Namespace) -> bool:
    """True when the command asks for the segment fit."""
    from estimator.reports.segments_report import wants_segments

    return wants_segments(args.segments, args.exclude, args.thruster_health, args.out_vehicle)


def cmd_segments(args: argparse.Namespace) -> int:
    """The segment fit (and the thruster health) of ``tpods estimate batch``."""
    from estimator.reports.segments_report import fit_run_by_segments

    rep = fit_run_by_segments(
        args.run_dir, args.thrust_table, segments=args.segments, exclude=args.exclude,
        window=args.window, structure=args.structure, model=args.model, estimate=args.estimate,
        fixed=args.fixed, initial=args.initial, clamp=args.clamp, max_iter=args.max_iter,
        sigma_pos_m=args.sigma_pos, sigma_yaw_rad=math.radians(args.sigma_yaw_deg),
        thruster_health=args.thruster_health, out_vehicle=args.out_vehicle, force=args.force,
        method=args.method)
    return report(args.out_folder, rep, args.json)
