"""``tpods run play`` (the input player) and ``tpods run plant`` (a simulated module)."""

from __future__ import annotations

import argparse
import math
import sys
import threading
import time
from pathlib import Path

from common.argtypes import fraction, nonneg_float, positive_float
from common.errors import UserError
from common.gcpause import frozen_heap
from common.outputs import add_force, optional_folder, stream_folder
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
from tpods.cli.stopping import stop_on_signals, valves_closed_exit, wait_for_stop


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


def _check_play_duties(args: argparse.Namespace, duty, lo: float, hi: float) -> None:
    """Every open duty of the input inside --duty-limits, checked before a valve opens
    (the controller would refuse the first bad one in the middle of the run)."""
    opened = duty[duty > 0]
    bad = opened[(opened < lo) | (opened > hi)]
    if duty.size and (duty.min() < 0 or duty.max() > 100):
        bad = duty[(duty < 0) | (duty > 100)]
    if not bad.size:
        return
    span = f"{duty[duty > 0].min():g}..{duty.max():g} %" if opened.size else f"{duty.min():g} %"
    if args.input == "phase-sine":
        a_max = max(min(50.0 - lo, hi - 50.0), 0.0)
        raise UserError(f"--amplitude {args.amplitude:g} puts the phase-sine duties at "
                        f"{50 - args.amplitude:g}..{50 + args.amplitude:g} %, outside --duty-limits "
                        f"{lo:g},{hi:g}: use --amplitude {a_max:g} or less")
    raise UserError(f"--input {args.input}: open duties span {span}, outside --duty-limits "
                    f"{lo:g},{hi:g} (first: {float(bad[0]):g} %)")


def cmd_play(args: argparse.Namespace) -> int:
    from bench.session import Terminated, parse_duty_steps, sigterm_raises
    from bench.valves import ValveController
    from common.plausible import check_duty_range
    from common.zenoh_net import open_session
    from estimator.plant.inputs import make_input
    from tpods.cli.run_vehicle import DEFAULT_DUTY_LIMITS, split_layout, vehicle_duty_limits
    from tpods.player import cmd_key, play

    structure, vehicle = split_layout(args)
    if args.duty_limits is None:
        args.duty_limits = (DEFAULT_DUTY_LIMITS if vehicle is None
                            else vehicle_duty_limits(vehicle))
    args.body = args.body or (vehicle.name if vehicle is not None else "tpods1")
    lim = parse_duty_steps(args.duty_limits.replace(":", ","))
    if len(lim) == 2:
        check_duty_range(lim[0], lim[1], f"--duty-limits {args.duty_limits}",
                         f"give --duty-limits {lim[1]:g},{lim[0]:g}")
    if len(lim) != 2 or not 0 < lim[0] <= lim[1] <= 100:
        raise UserError(f"--duty-limits must be LOW,HIGH within 0-100, got {args.duty_limits!r}")
    if args.watchdog_ms < 50:
        raise UserError("--watchdog-ms must be at least 50")
    if not args.prefix.strip("/"):
        raise UserError("--prefix must not be empty")
    clock = _clock(args)
    if structure is not None:
        if args.capture is not None:
            raise UserError("--capture is not built for --structure yet (one transcript per "
                            "controller)")
        urls = _module_urls(args.valves, [m.name for m in structure.modules])
        cmd_t, duty = make_input(args.input, args.duration, args.cmd_rate, args.amplitude,
                                 args.omega, n_channels=structure.n_channels)
    else:
        cmd_t, duty = make_input(args.input, args.duration, args.cmd_rate, args.amplitude,
                                 args.omega, n_channels=4 if vehicle is None else vehicle.n_channels)
        if vehicle is not None:
            from common.command_rules import onoff_scale_problem

            problem = onoff_scale_problem(duty, [i for i, t in enumerate(vehicle.thrusters)
                                                 if t.table is None and not t.dead])
            if problem is not None:
                raise UserError(f"--input {args.input}: {problem}")
    _check_play_duties(args, duty, lim[0], lim[1])
    if args.capture is True and args.out is None:
        raise UserError("--capture without a folder records into --out: give --out RUN_DIR or --capture DIR")
    out = None if args.out is None else stream_folder(args.out, force=args.force, command="tpods run play")
    capture = None
    if args.capture is not None:
        from bench.capture import capture_folder

        cap_dir = Path(out) if args.capture is True else capture_folder(args.capture, args.force,
                                                                        "tpods run play")
        capture = cap_dir / "valves.serial.jsonl"
    if structure is not None:
        return _play_structure(args, structure, urls, cmd_t, duty, lim, clock, out)
    if vehicle is not None and out is not None:
        vehicle.write(out)  # the folder of a vehicle run (docs/run-format.md)
    key = cmd_key(args.body, args.prefix)
    session = open_session(args)
    try:
        import zenoh

        # commands are small and rare: never dropped inside zenoh (block), sent at once
        pub = session.declare_publisher(key, encoding=zenoh.Encoding("application/json"),
                                        express=True,
                                        congestion_control=zenoh.CongestionControl.BLOCK)
        with sigterm_raises():
            try:
                with ValveController(args.valves, baudrate=args.valves_baud,
                                     duty_limits=(lim[0], lim[1]), capture=capture) as valves:
                    print(f"play: {args.input} for {cmd_t[-1] - cmd_t[0]:g} s on {args.valves}, "
                          f"commands on {key}"
                          + (f" (time scale {clock.scale:g})" if clock.scale != 1 else ""),
                          file=sys.stderr)
                    _wait_subscribers(args, [pub], key)
                    res = play(valves, cmd_t, duty, clock=clock, publish=pub.put, body=args.body,
                               out_dir=out, watchdog_ms=args.watchdog_ms, pwm_hz=args.pwm_hz,
                               heartbeat_s=args.heartbeat, announce_ahead_s=args.announce_ahead,
                               progress=not args.no_progress,
                               meta={"input": args.input, "duration_s": float(cmd_t[-1] - cmd_t[0]),
                                     "cmd_rate_hz": args.cmd_rate,
                                     **({"vehicle": vehicle.name} if vehicle is not None else {})})
            except (Terminated, KeyboardInterrupt) as exc:
                return valves_closed_exit(exc, "valves closed" + (f"; commands in {out}" if out else ""))
        pub.undeclare()
    finally:
        session.close()
    print(f"play {res.status}: {res.n_sent} commands sent, {res.n_holds} holds announced, "
          f"latest send {res.max_late_s * 1e3:.1f} ms behind schedule (lab), "
          f"valves closed (STATE? {' '.join(f'{x:g}' for x in res.final_state or ())})")
    if out:
        print(f"wrote {out}/commands.csv, " + ("vehicle.toml, " if vehicle is not None else "")
              + "run.json")
    if capture is not None:
        print(f"wrote {capture} (serial transcript)")
    return 0


def _wait_subscribers(args: argparse.Namespace, pubs: list, what: str) -> None:
    """``--wait-subscriber S``: the command publishers' subscribers, S seconds at most."""
    from common.zenoh_net import wait_matching

    if args.wait_subscriber > 0 and not wait_matching(pubs, args.wait_subscriber):
        print(f"play: warning: no subscriber of {what} after {args.wait_subscriber:g} s; "
              "playing (nothing records the commands over Zenoh)", file=sys.stderr)


def _module_urls(text: str, names: list[str]) -> dict[str, str]:
    """``--valves NAME=URL,NAME=URL`` for a structure: one controller per module, by name."""
    out: dict[str, str] = {}
    for item in text.split(","):
        name, sep, url = item.partition("=")
        if not sep or not name.strip() or not url.strip():
            raise UserError(f"--valves with --structure takes NAME=URL,NAME=URL (one per module: "
                            f"{', '.join(names)}), got {text!r}")
        out[name.strip()] = url.strip()
    missing = [n for n in names if n not in out]
    extra = [n for n in out if n not in names]
    if missing or extra:
        raise UserError(f"--valves names {', '.join(out)}; the structure's modules are "
                        f"{', '.join(names)}")
    return out


def _play_structure(args, structure, urls, cmd_t, duty, lim, clock, out) -> int:
    """``run play --structure``: every module's controller open at once (an ExitStack: every
    one is closed, OFF confirmed, on every exit path), one player loop."""
    import contextlib

    import zenoh

    from bench.session import Terminated, sigterm_raises
    from bench.valves import ValveController
    from common.zenoh_net import open_session
    from tpods.player import cmd_key, play

    names = [m.name for m in structure.modules]
    session = open_session(args)
    try:
        pubs = {n: session.declare_publisher(
            cmd_key(n, args.prefix), encoding=zenoh.Encoding("application/json"), express=True,
            congestion_control=zenoh.CongestionControl.BLOCK) for n in names}
        with sigterm_raises():
            try:
                with contextlib.ExitStack() as stack:
                    ctrls = [(n, stack.enter_context(ValveController(
                        urls[n], baudrate=args.valves_baud, duty_limits=(lim[0], lim[1]))))
                        for n in names]
                    print(f"play: {args.input} for {cmd_t[-1] - cmd_t[0]:g} s on structure "
                          f"{structure.name!r} ({', '.join(f'{n} at {urls[n]}' for n in names)}), "
                          f"commands on {args.prefix.strip('/')}/<module>/cmd", file=sys.stderr)
                    if out is not None:
                        structure.write(out)
                    _wait_subscribers(args, list(pubs.values()),
                                      f"{args.prefix.strip('/')}/<module>/cmd")
                    res = play(ctrls, cmd_t, duty, clock=clock,
                               publish={n: p.put for n, p in pubs.items()}, out_dir=out,
                               watchdog_ms=args.watchdog_ms, pwm_hz=args.pwm_hz,
                               heartbeat_s=args.heartbeat, announce_ahead_s=args.announce_ahead,
                               progress=not args.no_progress,
                               meta={"input": args.input, "structure": structure.name,
                                     "duration_s": float(cmd_t[-1] - cmd_t[0]),
                                     "cmd_rate_hz": args.cmd_rate})
            except (Terminated, KeyboardInterrupt) as exc:
                return valves_closed_exit(exc, "every module's valves closed"
                                          + (f"; commands in {out}" if out else ""))
        for p in pubs.values():
            p.undeclare()
    finally:
        session.close()
    print(f"play {res.status}: {res.n_sent} commands sent to {len(names)} modules, "
          f"{res.n_holds} holds announced, latest send {res.max_late_s * 1e3:.1f} ms behind "
          f"schedule (lab), valves closed (STATE? {' '.join(f'{x:g}' for x in res.final_state or ())})")
    if out:
        print(f"wrote {out}/commands.csv ({len(names) * 4} channels), structure.toml, run.json")
    return 0


def cmd_plant(args: argparse.Namespace) -> int:
    import numpy as np

    from bench.emulators import EmulatedValveController, serve_pty
    from common.thrust_table import load_thrust_table
    from estimator.plant.model import PlantParams
    from tpods.plant_loop import MocapNoise, PlantLoop, push_sink, udp_sink

    truth_out = optional_folder(args.truth_out, force=args.force, option="--truth-out",
                                command="tpods run plant")
    clock = _clock(args)
    table = load_thrust_table(args.thrust_table)
    ct = cr = kb = 0.0
    if args.friction:
        try:
            ct, cr, kb = (float(x) for x in args.friction.split(","))
        except ValueError:
            raise UserError(f"--friction must be CT,CR,KB, got {args.friction!r}") from None
    params = PlantParams(args.mass, args.izz, ct=ct, cr=cr, kb=kb)
    noise = MocapNoise(args.noise_pos, math.radians(args.noise_yaw_deg), args.occlusion)
    stop = threading.Event()
    from tpods.cli.run_vehicle import split_layout

    structure, vehicle = split_layout(args)
    args.body = args.body or (vehicle.name if vehicle is not None else "tpods1")
    if vehicle is not None and args.thrust_table is not None:
        vehicle.check_table_option()
        vehicle = vehicle.with_table(table)
    if structure is not None or vehicle is not None:
        from tpods.plant_loop import StructureThrust, StructureValves

        g = (structure or vehicle).initial_guess()  # [body] values where given, else the geometry
        given = {a.lstrip("-").split("=")[0] for a in sys.argv if a.startswith("--")}
        params = PlantParams(args.mass if "mass" in given else g["mass"],
                             args.izz if "izz" in given else g["izz"], ct=ct, cr=cr, kb=kb,
                             cx=g["cx"], cy=g["cy"])
    if vehicle is not None:  # one N-channel driver
        valves = EmulatedValveController(vehicle.n_channels)
        ctrls = [valves]
    elif structure is not None:
        ctrls = [EmulatedValveController(4) for _ in structure.modules]
        valves = StructureValves(ctrls)
        table = StructureThrust(structure)
    else:
        valves = EmulatedValveController(4)
        ctrls = [valves]
    session = bridge = source = None
    bridge_thread = None
    if args.mocap == "zenoh":
        from common.zenoh_net import open_session
        from mocap_bridge.bridge import Bridge
        from mocap_bridge.sources.push import PushSource

        session = open_session(args)
        source = PushSource("plant")
        sink = push_sink(source, args.body)
        bridge = Bridge(session)
        bridge_thread = threading.Thread(target=bridge.run, args=(source, stop), daemon=True)
    elif args.mocap.startswith("udp:"):
        sink = udp_sink(udp_target(args.mocap), args.body, args.udp_block_size or None)
    else:
        raise UserError(f"--mocap must be zenoh or udp:HOST:PORT, got {args.mocap!r}")
    if vehicle is not None:  # its valve dead time and rise too
        from tpods.plant_vehicle import vehicle_plant

        plant = vehicle_plant(valves, params, vehicle, sink, clock=clock,
                              pose_rate_hz=args.pose_rate, noise=noise, seed=args.seed)
    else:
        plant = PlantLoop(valves, params, table, sink, clock=clock, pose_rate_hz=args.pose_rate,
                          noise=noise, seed=args.seed)
    def stop_on_error() -> None:  # the plant loop stopped on an error
        if plant.error is not None:
            stop.set()

    sys.setswitchinterval(2e-4)  # the emulated controller reacts within a fraction of a ms
    servers = [serve_pty(c) for c in ctrls]
    try:
        # until --duration, Ctrl-C/SIGTERM or a plant error; no long GC pause meanwhile
        with stop_on_signals(stop), frozen_heap():
            if bridge_thread is not None:
                bridge_thread.start()
            plant.start()
            if structure is None:  # a module or a vehicle: one controller
                print(f"valves: {servers[0].path}", flush=True)
            else:
                for m, srv in zip(structure.modules, servers, strict=True):
                    print(f"valves {m.name}: {srv.path}", flush=True)
            print(f"plant: m {params.mass_kg:g} kg, Izz {params.izz_kgm2:g} kg m^2"
                  + (f", centre of mass ({params.cx:g}, {params.cy:g}) m"
                     if structure or vehicle else "")
                  + f", {args.pose_rate:g} Hz poses of {args.body} ({args.mocap}); Ctrl-C to stop",
                  file=sys.stderr, flush=True)
            wait_for_stop(stop, args.duration, stop_on_error, every_s=0.2)
    finally:
        stop.set()
        plant.stop()
        for srv in servers:
            srv.stop()
        if source is not None:
            source.finish()
        if bridge_thread is not None:
            bridge_thread.join(timeout=5.0)
        if session is not None:
            session.close()
    if truth_out is not None:
        with truth_out.writing() as d:
            t, s = plant.truth_arrays()
            np.savetxt(d / "truth.csv", np.column_stack([t, s]), delimiter=",",
                       header="t_lab,x,y,psi,u,v,r", comments="", fmt="%.12g")
            with (d / "switches.csv").open("w") as fh:
                fh.write("t_lab," + ",".join(f"d{i + 1}" for i in range(len(valves.duties))) + "\n")
                for ts, du in plant.switches:
                    fh.write(f"{ts:.9f}," + ",".join(f"{x:g}" for x in du) + "\n")
    print(f"plant: {plant.frames} poses ({plant.occluded} occluded), {len(plant.switches)} valve "
          f"changes, {sum(c.watchdog_trips for c in ctrls)} watchdog trip(s)", file=sys.stderr)
    if plant.error is not None:
        raise UserError(f"the simulated module stopped after {plant.frames} poses: {plant.error}")
    return 0


def udp_target(spec: str) -> tuple[str, int]:
    """``udp:HOST:PORT`` (HOST may be empty: 127.0.0.1) as a resolved (address, port), or
    one UserError naming --mocap and what is wrong, before anything starts."""
    import socket

    host, sep, port_text = spec[4:].rpartition(":")
    try:
        port = int(port_text)
    except ValueError:
        port = None
    if not sep or port is None:
        raise UserError(f"--mocap must be udp:HOST:PORT, got {spec!r}")
    if not 1 <= port <= 65535:
        raise UserError(f"--mocap {spec}: port {port} is out of range (1-65535)")
    host = host or "127.0.0.1"
    try:
        addr = socket.getaddrinfo(host, port, socket.AF_INET, socket.SOCK_DGRAM)[0][4][0]
    except (socket.gaierror, UnicodeError) as exc:
        raise UserError(f"--mocap {spec}: cannot resolve host {host!r} "
                        f"({getattr(exc, 'strerror', None) or exc})") from None
    return addr, port
