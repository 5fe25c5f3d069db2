"""``tpods calibrate thrust RUN --mass KG --segments LEN|auto``: a vehicle's per-thruster
in-flight efficiencies from a whole run fitted by segments (:mod:`estimator.shooting`), with
the mass known; writes the vehicle file with the efficiencies in its forces and a dead
thruster marked ``health = "dead"``."""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import replace

import numpy as np

from common.errors import UserError
from estimator.shooting.segments import parse_segments


def wanted(args: argparse.Namespace) -> bool:
    return args.segments is not None and parse_segments(args.segments) != math.inf


def cmd_thrust_segments(args: argparse.Namespace) -> int:
    from common.argtypes import vehicle_file
    from common.outputs import result_output
    from common.runfolder import read_run
    from common.vehicle_toml import vehicle_document
    from estimator.batch.thrust_calibration.vehicle import calibrated_vehicle
    from estimator.shooting.health import thruster_health

    if args.per != "thruster":
        raise UserError(f"--segments calibrates each thruster: drop --per {args.per}")
    if args.izz is not None or args.thrust_table is not None:
        raise UserError("--segments estimates Izz with the efficiencies of a vehicle of on/off "
                        "valves: drop --izz and --thrust-table")
    run = read_run(args.run_dir, vehicle_file(args.vehicle) if args.vehicle else None)
    v = run.structure
    if getattr(v, "kind", None) != "vehicle" or any(t.table is not None for t in v.thrusters):
        raise UserError(f"{run.path}: --segments calibrates a vehicle of on/off valves "
                        "(--vehicle FILE)")
    if args.window:
        run = run.window(*args.window)
    out = result_output(args.out, "vehicle.toml", force=args.force,
                        command="tpods calibrate thrust")
    rep = thruster_health(run.pose_t, run.pose, v, run.cmd_t, run.duty_pct, mass_kg=args.mass,
                          sigma_pos_m=args.sigma_pos,
                          sigma_yaw_rad=math.radians(args.sigma_yaw_deg),
                          length_s=parse_segments(args.segments))
    fit = rep.fit
    if not fit.converged:
        raise UserError(f"{run.path}: the calibration by segments did not converge "
                        f"({fit.message}); no vehicle written")
    names, values, sig = [], [], []
    for j, t in enumerate(rep.thrusters):
        if t.verdict in ("dead", "reversed") or not math.isfinite(t.sigma):
            continue
        # the known mass's uncertainty moves every efficiency in proportion
        s = math.hypot(t.sigma, t.efficiency * args.mass_sigma / args.mass)
        names.append(f"efficiency.{j + 1}")
        values.append(t.efficiency)
        sig.append(s)
    new = calibrated_vehicle(v, names, values, np.diag(np.square(sig)), str(out.main))
    verdict = {t.name: t.verdict for t in rep.thrusters}
    new = replace(new, thrusters=tuple(replace(t, health=verdict[t.name]) for t in new.thrusters))
    doc = {"run": str(run.path), "mass_kg": args.mass, "mass_sigma_kg": args.mass_sigma,
           "thruster_health": [t.to_dict() for t in rep.thrusters], **fit.to_dict(),
           "out": str(out.main)}
    import tomli_w

    with out.writing_main() as (main, d):
        main.write_text(f"# tpods calibrate thrust {run.path} --segments: in-flight efficiencies "
                        f"(--mass {args.mass:g}); force_sigma_n = their total sigma\n"
                        + tomli_w.dumps(vehicle_document(new.name, new.thrusters, new.valves,
                                                         new.body, main.parent,
                                                         supplies=new.supplies)))
        if d is not None:
            (d / "calibration.json").write_text(json.dumps(doc, indent=2, default=float) + "\n")
    for w in fit.warnings:
        print(f"tpods: warning: {w}", file=sys.stderr)
    if args.mass_sigma == 0:
        print("tpods: warning: --mass-sigma not given: the efficiencies' sigma leaves out the "
              "known mass's uncertainty", file=sys.stderr)
    if args.json:
        print(json.dumps(doc, indent=2, default=float))
        return 0
    print(f"thrust calibration by segments on {run.path} ({len(fit.t)} poses in {fit.plan.n} "
          f"segments of {fit.plan.length_s:g} s); {fit.message}, {fit.iterations} iterations")
    for line in rep.lines():
        print(line)
    print(f"  wrote {out.main}" + (", calibration.json" if out.is_folder else ""))
    return 0
