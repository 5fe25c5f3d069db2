"""``tpods run play`` (the input player) and ``tpods run plant`` (a simulated module)."""

from __future__ import annotations

import argparse
import math
import sys
import threading
import time

from common.argtypes import fraction, nonneg_float, positive_float
from common.errors import UserError
from common.outputs import add_force, optional_folder
from common.zenoh_net import add_zenoh_options
from tpods.cli.options import (
    add_cmd_rate,
    add_duty_limits,
    add_input_choice,
    add_no_progress,
    add_noise_seed,
    add_pose_rate,
    add_sine_amplitude,
    add_structure_or_vehicle,
    add_watchdog_ms,
)
from tpods.cli.parser import command, group
from tpods.cli.stopping import stop_on_signals, valves_closed_exit


def register(sub) -> None:
    """Add the ``run`` group to the `tpods` parser."""
    g = group(sub, "run", "run a module: play an input on its valves, simulate a module")

    p = command(
        g, "play", cmd_play, help="play an input sequence on a module's valves",
        description="Send an input sequence to a protocol-v1 valve controller, publish each command "
                    "on tpods/<body>/cmd (JSON, schema tpods.cmd/1) and record commands.csv. The "
                    "controller watchdog is armed and fed; every valve is closed (OFF confirmed by "
                    "STATE?) on every exit path.")
    p.add_argument("--valves", required=True, metavar="URL",
                   help="valve controller: device path or pyserial URL (socket://HOST:PORT, ...); "
                        "with --structure one per module: NAME=URL,NAME=URL")
    add_structure_or_vehicle(p, "play on a structure (structure.toml): every module's controller from "
                        "--valves NAME=URL,..., each module's commands on tpods/<module>/cmd, one "
                        "commands.csv with 4 columns per module; any controller's lost link "
                        "closes them all",
                             "play on a vehicle (vehicle.toml): one N-channel valve driver at "
                             "--valves, its N duties d1..dN on tpods/<body>/cmd (body: the "
                             "vehicle's name), vehicle.toml beside commands.csv; --duty-limits "
                             "defaults to the vehicle's duty range (on/off valves: 1,100)")
    add_input_choice(p)
    p.add_argument("--duration", type=positive_float, default=None, metavar="S",
                   help="seconds of input (default 120; a commands.csv input: its whole length, "
                        "cut to S when given)")
    p.add_argument("--body", default=None,
                   help="body name (default tpods1; with --vehicle the vehicle's name)")
    p.add_argument("--out", default=None, metavar="RUN_DIR",
                   help="write commands.csv and run.json here")
    add_force(p)
    add_cmd_rate(p)
    add_sine_amplitude(p)
    p.add_argument("--omega", type=positive_float, default=1.0, help="phase-sine rad/s (default 1)")
    p.add_argument("--pwm-hz", type=positive_float, default=10.0, help="PWM frequency (default 10)")
    add_watchdog_ms(p)
    add_duty_limits(p)
    p.add_argument("--heartbeat", type=positive_float, default=0.1, metavar="S",
                   help="re-announce the command in force after S s without one (default 0.1)")
    p.add_argument("--announce-ahead", type=nonneg_float, default=0.0, metavar="S",
                   help="publish each command S s before it is due, stamped with when it is due "
                        "(the live estimator then never re-runs a pose for it; commands.csv keeps "
                        "the measured switch times); default 0: after the switch, with its "
                        "measured time")
    p.add_argument("--valves-baud", type=int, default=115200, help="baud rate (default 115200)")
    p.add_argument("--prefix", default="tpods", help="key prefix (default tpods)")
    p.add_argument("--wait-subscriber", type=nonneg_float, default=0.0, metavar="S",
                   help="before the first command, wait up to S seconds for a subscriber of the "
                        "command key (the live estimator or a recorder started at the same time; "
                        "none by then: a warning and the run is played; default 0)")
    _clock_options(p)
    p.add_argument("--capture", nargs="?", const=True, default=None, metavar="DIR",
                   help="record a byte-exact transcript of the valve controller's serial link "
                        "(valves.serial.jsonl, docs/recordings.md) into the --out folder, or into DIR")
    add_no_progress(p)
    add_zenoh_options(p)

    s = command(
        g, "plant", cmd_plant, help="serve a simulated module behind an emulated valve controller",
        description="Serve an emulated protocol-v1 valve controller on a pty (prints its path) and "
                    "simulate the module it drives: poses with mocap noise published on "
                    "tpods/mocap/<body>/pose through the bridge, or sent as Vicon Tracker UDP "
                    "datagrams. Runs until Ctrl-C, SIGTERM or --duration.")
    s.add_argument("--mass", type=positive_float, default=2.268, help="true mass, kg (default 2.268)")
    s.add_argument("--izz", type=positive_float, default=3.78e-3,
                   help="true Izz, kg m^2 (default 3.78e-3)")
    s.add_argument("--friction", default=None, metavar="CT,CR,KB",
                   help="true friction terms (default none)")
    s.add_argument("--thrust-table", default=None, metavar="F",
                   help="true thrust table (default the paper's Table 2)")
    add_pose_rate(s)
    s.add_argument("--noise-pos", type=nonneg_float, default=0.01, help="m (default 0.01)")
    s.add_argument("--noise-yaw-deg", type=nonneg_float, default=1.0, help="deg (default 1)")
    s.add_argument("--occlusion", type=fraction, default=0.0, help="fraction of occluded frames")
    add_noise_seed(s)
    s.add_argument("--body", default=None,
                   help="body name (default tpods1; with --vehicle the vehicle's name)")
    add_structure_or_vehicle(s, "simulate a structure (structure.toml): one emulated controller per module "
                        "(their paths printed as 'valves NAME: PATH'), the truth from its [body] "
                        "(centre of mass included), poses of its tracked frame",
                             "simulate a vehicle (vehicle.toml): one emulated N-channel valve "
                             "driver (its path printed as 'valves: PATH'), its thrusters with their "
                             "valve delay and rise, the truth from its [body] where --mass/--izz "
                             "are not given, poses of its tracked frame")
    s.add_argument("--mocap", default="zenoh", metavar="zenoh|udp:HOST:PORT",
                   help="publish through the bridge over zenoh (default) or send Tracker UDP")
    s.add_argument("--udp-block-size", type=int, choices=(0, 256, 512, 1024), default=1024,
                   metavar="BYTES",
                   help="udp: pad every datagram to this size as Tracker's Data Block Size does "
                        "(256, 512 or 1024; 0 for no padding; default 1024)")
    s.add_argument("--duration", type=positive_float, default=None, metavar="S",
                   help="stop after S s (default: Ctrl-C)")
    s.add_argument("--truth-out", default=None, metavar="DIR",
                   help="on exit write truth.csv and switches.csv here")
    add_force(s, "--truth-out")
    _clock_options(s)
    add_zenoh_options(s)


def _clock_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--time-scale", type=positive_float, default=1.0, metavar="X",
                   help="lab seconds per real second: >1 only with a simulated module "
                        "(default 1, real time)")
    p.add_argument("--clock-origin", type=float, default=None, metavar="EPOCH_S",
                   help="host time at which lab and host clocks coincide; give the same value to "
                        "the player and the simulated module (default now)")


def _clock(args):
    from tpods.clock import LabClock

    if args.time_scale != 1.0 and args.clock_origin is None:
        raise UserError("--time-scale other than 1 needs --clock-origin (the same on every process)")
    return LabClock(args.time_scale, args.clock_origin if args.clock_origin is not None else time.time())


def cmd_play(args: argparse.Namespace) -> int:
    from bench.session import Terminated, sigterm_raises
    from common.layout_files import split_layout
    from common.zenoh_net import open_session
    from tpods.play_session import plan_play, play_plan

    structure, vehicle = split_layout(args.structure)
    plan = plan_play(args.valves, input_name=args.input, duration_s=args.duration,
                     cmd_rate_hz=args.cmd_rate, amplitude_pct=args.amplitude,
                     omega_rad_s=args.omega, structure=structure, vehicle=vehicle,
                     duty_limits=args.duty_limits, watchdog_ms=args.watchdog_ms,
                     prefix=args.prefix, body=args.body, out=args.out, force=args.force,
                     capture=args.capture)
    clock = _clock(args)
    out = plan.out
    session = open_session(args)
    try:
        with sigterm_raises():
            try:
                res = play_plan(plan, session, clock=clock, prefix=args.prefix,
                                valves_baud=args.valves_baud, watchdog_ms=args.watchdog_ms,
                                pwm_hz=args.pwm_hz, heartbeat_s=args.heartbeat,
                                announce_ahead_s=args.announce_ahead,
                                progress=not args.no_progress,
                                wait_subscriber_s=args.wait_subscriber,
                                on_info=lambda line: print(line, file=sys.stderr),
                                on_warning=lambda w: print(f"play: warning: {w}", file=sys.stderr))
            except (Terminated, KeyboardInterrupt) as exc:
                what = "valves closed" if structure is None else "every module's valves closed"
                return valves_closed_exit(exc, what + (f"; commands in {out}" if out else ""))
    finally:
        session.close()
    closed = f"valves closed (STATE? {' '.join(f'{x:g}' for x in res.final_state or ())})"
    late = f"latest send {res.max_late_s * 1e3:.1f} ms behind schedule (lab)"
    if structure is not None:
        n = len(plan.urls)
        print(f"play {res.status}: {res.n_sent} commands sent to {n} modules, "
              f"{res.n_holds} holds announced, {late}, {closed}")
        if out:
            print(f"wrote {out}/commands.csv ({n * 4} channels), structure.toml, run.json")
        return 0
    print(f"play {res.status}: {res.n_sent} commands sent, {res.n_holds} holds announced, "
          f"{late}, {closed}")
    if out:
        print(f"wrote {out}/commands.csv, " + ("vehicle.toml, " if vehicle is not None else "")
              + "run.json")
    if plan.capture is not None:
        print(f"wrote {plan.capture} (serial transcript)")
    return 0


def cmd_plant(args: argparse.Namespace) -> int:
    from common.layout_files import split_layout
    from tpods.plant_session import build_plant

    truth_out = optional_folder(args.truth_out, force=args.force, option="--truth-out",
                                command="tpods run plant")
    clock = _clock(args)
    structure, vehicle = split_layout(args.structure)
    given = {a.lstrip("-").split("=")[0] for a in sys.argv if a.startswith("--")}
    layout = structure is not None or vehicle is not None
    sim = build_plant(mass_kg=args.mass if "mass" in given or not layout else None,
                      izz_kgm2=args.izz if "izz" in given or not layout else None, clock=clock,
                      thrust_table=args.thrust_table, friction=args.friction,
                      structure=structure, vehicle=vehicle, body=args.body, mocap=args.mocap,
                      zenoh_options=args, udp_block_size=args.udp_block_size,
                      pose_rate_hz=args.pose_rate, noise_pos_m=args.noise_pos,
                      noise_yaw_rad=math.radians(args.noise_yaw_deg), occlusion=args.occlusion,
                      seed=args.seed)

    def ready(paths: list[str], line: str) -> None:
        for p in paths:
            print(p, flush=True)
        print(line, file=sys.stderr, flush=True)

    stop = threading.Event()
    # until --duration, Ctrl-C/SIGTERM or a plant error
    with stop_on_signals(stop):
        sim.serve(stop, args.duration, pose_rate_hz=args.pose_rate, on_ready=ready)
    if truth_out is not None:
        with truth_out.writing() as d:
            sim.write_truth(d)
    print(sim.summary(), file=sys.stderr)
    if sim.plant.error is not None:
        raise UserError(f"the simulated module stopped after {sim.plant.frames} poses: "
                        f"{sim.plant.error}")
    return 0
