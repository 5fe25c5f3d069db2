"""Sub-commands of the estimator package: ``tpods sim`` (and the estimators as they land)."""

from __future__ import annotations

import argparse
import math
import sys

from common.argtypes import float_list, fraction, nonneg_float, positive_float
from common.constants import PAPER_IZZ_KGM2, PAPER_MASS_KG
from common.errors import UserError
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

    from common.thrust_table import load_thrust_table
    from estimator.plant.inputs import DEFAULT_DURATION_S, INPUT_NAMES, make_input
    from estimator.plant.model import PlantParams
    from estimator.plant.sim import SimConfig, simulate, summary_lines, write_sim_run

    out = ResultFolder(args.out, force=args.force, command="tpods sim")
    table = load_thrust_table(args.thrust_table)
    structure = sim_structure(args, table)
    n_channels = 4 if structure is None else structure.n_channels
    generated = args.input in INPUT_NAMES
    if generated:  # sizes and duties from the options, before anything is allocated
        check_sim_size(args, args.duration or DEFAULT_DURATION_S)
        for t in ([table] if structure is None else structure.tables()):
            check_phase_sine(args, t)
    cmd_t, duty = make_input(args.input, args.duration, args.cmd_rate, args.amplitude, args.omega,
                             n_channels=n_channels)
    if not generated:
        check_sim_size(args, float(cmd_t[-1] - cmd_t[0]), n_cmds=len(cmd_t))
    ct, cr, kb = args.friction or (0.0, 0.0, 0.0)
    ax, ay = args.tilt or (0.0, 0.0)
    body = structure.body if structure is not None else None
    if getattr(structure, "kind", None) == "vehicle" and not structure.is_single_at_origin and (
            (args.mass is None and body.mass_kg is None) or (args.izz is None and body.izz_kgm2 is None)):
        raise UserError(f"{structure.source}: states no [body] mass_kg and izz_kgm2: give --mass "
                        "and --izz (the paper's 2.3 kg module is not this vehicle)")
    mass = args.mass or (body and body.mass_kg) or PAPER_MASS_KG
    izz = args.izz or (body and body.izz_kgm2) or PAPER_IZZ_KGM2
    if args.com is not None and structure is None:
        raise UserError("--com is a structure's centre of mass: give --structure F too")
    cx, cy = args.com or (body and body.com_m) or (0.0, 0.0)
    params = PlantParams(mass, izz, ct=ct, cr=cr, kb=kb, ax=ax, ay=ay,
                         **({"cx": cx, "cy": cy} if (cx, cy) != (0.0, 0.0) else {}))
    cfg = SimConfig(pose_rate_hz=args.pose_rate, noise_pos_m=args.noise_pos,
                    noise_yaw_rad=math.radians(args.noise_yaw_deg), drop=args.drop,
                    seed=args.seed, clamp=args.clamp)
    try:
        thrust_t, virtual = (None, None) if structure is None else \
            structure.input_profile(cmd_t, duty, clamp=args.clamp)
        res = simulate(cmd_t, duty, params, table, cfg, thrust_n=virtual, thrust_t=thrust_t)
    except UserError as exc:  # a duty of a commands.csv outside the table: name the options
        raise UserError(f"--input {args.input}: {clamp_named(exc)}") from None
    with out.writing() as d:
        write_sim_run(res, d, args.input, args.thrust_table or "built-in Table 2")
        if structure is not None:
            write_sim_structure(d, structure)
    print(f"wrote {out.path}")
    for line in summary_lines(res):
        print("  " + line)
    if structure is not None:
        print(f"  {structure.kind:<9}       {structure.name}: {structure.parts_text()}, centre of mass "
              f"({cx:+.4g}, {cy:+.4g}) m in the tracked frame")
        for line in body_note(structure):
            print("  " + line)
    return 0


def sim_structure(args: argparse.Namespace, table):
    """The ``--structure`` of ``tpods sim`` with ``--thrust-table`` applied to the modules
    without their own table, or None."""
    from common.layout_files import load_layout

    if args.structure is None:
        return None
    s = load_layout(args.structure)
    if args.thrust_table is not None:
        s.check_table_option()
        s = s.with_table(table)
    return s


def body_note(structure) -> list[str]:
    """What ``tpods estimate`` will make of the [body] values of the structure.toml copied
    into a simulated run (the copy is the user's file as given; the truth is in run.json)."""
    known, priors = structure.body.known(), structure.body.priors()
    if not known and not priors:
        return []
    parts = []
    if known:
        parts.append("fixes " + ", ".join(f"{n} = {v:g}" for n, v in known.items()) + " (known)")
    if priors:
        parts.append("takes a prior on " + ", ".join(priors))
    return [f"[body]          tpods estimate {' and '.join(parts)} from the run's structure.toml; "
            "to estimate them, give the truth with --mass/--izz/--com and leave them out of "
            "[body]"]


def write_sim_structure(folder, structure) -> None:
    """Make a simulated run folder a structure run: its structure.toml (self-contained)
    and the structure named in run.json."""
    import json

    from common.runwriter import write_json_atomic
    from common.vehicle import Vehicle

    structure.write(folder)
    meta_file = folder / "run.json"
    meta = json.loads(meta_file.read_text())
    if isinstance(structure, Vehicle):
        meta["settings"]["vehicle"] = {"name": structure.name, "thrusters": structure.describe()}
    else:
        meta["settings"]["structure"] = {"name": structure.name, "modules": structure.describe()}
    write_json_atomic(meta_file, meta)


def clamp_named(exc: Exception) -> str:
    """A thrust table's duty error with the option to give (``--clamp``) named."""
    return str(exc).replace("(use the clamp option to saturate)", "(add --clamp to saturate)")


def check_sim_size(args: argparse.Namespace, duration_s: float, n_cmds: int | None = None) -> None:
    """Refuse a simulation that will not fit in memory (naming the option that makes it
    big) and announce one that takes long; from the options, before any allocation."""
    import tpods.cli.sizes as sizes

    n_poses = sizes.samples(duration_s, args.pose_rate)
    cmds = sizes.samples(duration_s, args.cmd_rate) if n_cmds is None else float(n_cmds)
    n_bytes, seconds = sizes.sim_cost(n_poses, cmds)
    span = (f"--duration {sizes.number(duration_s)} s" if n_cmds is None or args.duration
            else f"--input {args.input} ({sizes.number(duration_s)} s)")
    if n_cmds is None:
        what = (f"{span} at --pose-rate {sizes.number(args.pose_rate)} Hz and --cmd-rate "
                f"{sizes.number(args.cmd_rate)} Hz is {sizes.samples_text(duration_s, args.pose_rate)} "
                f"poses and {sizes.samples_text(duration_s, args.cmd_rate)} command rows")
        rate = ("--cmd-rate" if sizes.SIM_BYTES_PER_CMD * cmds > sizes.SIM_BYTES_PER_POSE * n_poses
                else "--pose-rate")
        fix = f"lower {rate} or --duration"
    else:
        what = (f"{span} at --pose-rate {sizes.number(args.pose_rate)} Hz is "
                f"{sizes.samples_text(duration_s, args.pose_rate)} poses")
        fix = "lower --pose-rate or --duration" if args.duration else \
            "lower --pose-rate or give a shorter --duration"
    sizes.refuse_if_too_big(what, n_bytes, fix)
    sizes.announce(seconds, f"simulating {sizes.number(n_poses)} poses")


def check_phase_sine(args: argparse.Namespace, table) -> None:
    """The phase-sine's duties 50 +/- --amplitude against 0..100 % and the thrust table's
    valid range (unless --clamp); --omega against the command rate."""
    if args.input != "phase-sine":
        return
    a, lo, hi = args.amplitude, *table.duty_range
    a_max = min(50.0 - lo, hi - 50.0)
    d_lo, d_hi = 50.0 - a, 50.0 + a
    if d_lo < 0 or d_hi > 100:
        raise UserError(f"--amplitude {a:g} puts the phase-sine duties at {d_lo:g}..{d_hi:g} %, "
                        f"outside 0..100 %; the thrust table's valid range {lo:g}-{hi:g} % allows "
                        f"--amplitude {max(a_max, 0):g} or less")
    if a > 0 and (d_lo < lo or d_hi > hi) and not getattr(args, "clamp", False):
        raise UserError(f"--amplitude {a:g} puts the phase-sine duties at {d_lo:g}..{d_hi:g} %, "
                        f"outside the thrust table's valid range {lo:g}-{hi:g} %: use --amplitude "
                        f"{max(a_max, 0):g} or less, or add --clamp to saturate")
    nyquist = math.pi * args.cmd_rate
    if args.omega > nyquist:
        print(f"tpods: warning: --omega {args.omega:g} rad/s is above the Nyquist frequency of "
              f"--cmd-rate {args.cmd_rate:g} Hz ({nyquist:.4g} rad/s): the held commands alias "
              "to a slower sine", file=sys.stderr)
