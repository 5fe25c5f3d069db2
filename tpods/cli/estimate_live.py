"""``tpods estimate live``: a thin shell over :mod:`estimator.live.runtime`."""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import math
import sys
import threading
from pathlib import Path

from common.argtypes import clock_offset_arg, nonneg_float, positive_float
from common.clock_ping import PingPoller, clock_key
from common.errors import UserError
from common.outputs import add_force, stream_folder
from common.zenoh_net import add_zenoh_options
from estimator.reports.estimate_text import budget_lines, filter_budget
from tpods.cli.estimate_ekf import add_batch_options
from tpods.cli.estimate_output import write_json
from tpods.cli.options import add_key_prefixes, add_structure_or_vehicle
from tpods.cli.parser import command
from tpods.cli.stopping import zenoh_session


def register(est) -> None:
    """Add ``live`` to the ``tpods estimate`` group."""
    p = command(
        est, "live", cmd_live, help="estimate mass and Izz live from Zenoh poses and commands",
        description="Subscribe to tpods/mocap/<body>/pose and tpods/<body>/cmd, align them (commands "
                    "are a zero-order hold; each pose is filtered as it arrives, and a command that "
                    "arrives after poses it governs makes the filter re-run them), run the EKF (or "
                    "LS then EKF) pose by pose and publish tpods/<body>/estimate (re-run estimates "
                    "again, with rev > 0 and revised true). "
                    "With --out, what it saw is recorded as a run folder for `tpods estimate batch`.")
    p.add_argument("--body", default=None,
                   help="body name: its poses are tpods/mocap/<body>/pose (default tpods1; with "
                        "--structure or --vehicle its name)")
    add_structure_or_vehicle(p, "structure.toml: a rigid body moved by several modules; commands "
                        "from tpods/<module>/cmd of every module in F, merged; estimates mass, Izz "
                        "about the centre of mass and the centre of mass (ls-ekf only)",
                             "vehicle.toml: its N duties d1..dN on tpods/<body>/cmd, its "
                             "valve delay and rise applied; estimates as --structure (ls-ekf only)")
    p.add_argument("--thrust-table", default=None, metavar="F",
                   help="thrust table TOML, e.g. from `tpods bench fit` (default the paper's Table 2; "
                        "with --structure: for the modules without their own)")
    p.add_argument("--method", choices=("ekf", "ls-ekf"), default=None,
                   help="ekf, or ls-ekf: batch LS on the first --ls-window seconds in the background, "
                        "then the filter restarts from it (default ekf; ls-ekf with --structure or "
                        "--vehicle)")
    p.add_argument("--out", default=None, metavar="RUN_DIR",
                   help="record a run folder here; a file X.mcap: only the Zenoh streams, in MCAP")
    p.add_argument("--mcap", action="store_true",
                   help="with --out RUN_DIR: also record the pose, command and estimate streams "
                        "to RUN_DIR/recording.mcap")
    add_force(p)
    p.add_argument("--rate", type=nonneg_float, default=10.0, metavar="HZ",
                   help="estimate publish rate, Hz; 0 = after every pose update (default 10)")
    p.add_argument("--max-wait-ms", type=nonneg_float, default=0.0, metavar="MS",
                   help="longest a pose waits for a late command, ms, counted from the earlier of "
                        "its capture and arrival times (default 0: each pose is filtered as it "
                        "arrives; a command that comes after poses it governs makes the filter "
                        "re-run them and publish their estimates again, marked revised)")
    p.add_argument("--rewind-s", type=nonneg_float, default=2.0, metavar="S",
                   help="a command that arrives after the poses it governs, but at most S lab "
                        "seconds after its time, makes the filter re-run from before it "
                        "(default 2; 0: such commands are counted as late and not used live)")
    p.add_argument("--resume", default=None, metavar="RUN_DIR",
                   help="continue from the run folder of a live estimator that died: its "
                        "commands and poses are taken in first (and recorded again in --out, "
                        "another folder), then the live stream; the time it was down is "
                        "named as a gap")
    p.add_argument("--clock-offset-ms", type=clock_offset_arg, default="none",
                   metavar="auto|none|MS",
                   help="the mocap host's clock minus the player host's: none (default) "
                        "applies nothing but measures it from the streams and reports it; auto "
                        "also takes the measured offset, once settled, off every later pose "
                        "time (the measurement cannot tell an offset from unequal path delays: "
                        "on one host it reads a few ms); MS takes MS ms off every pose time "
                        "(the offset left is measured and reported)")
    p.add_argument("--duration", type=positive_float, default=None, metavar="S",
                   help="stop after S seconds (default: Ctrl-C / SIGTERM)")
    p.add_argument("--exit-on-end", action="store_true",
                   help="stop shortly after the player announces the end of its input")
    add_key_prefixes(p)
    p.add_argument("--json", action="store_true", help="print the final summary as one JSON object")
    p.add_argument("--quiet", action="store_true", help="no live console line")
    add_batch_options(p)
    add_zenoh_options(p)


def cmd_live(args: argparse.Namespace) -> int:
    import tpods
    from common.console import Console as _Console
    from common.mcap.process import McapProcessLog
    from common.outputs import is_mcap, stream_file
    from common.thrust_table import load_thrust_table
    from estimator.live.recorder import record_streams
    from estimator.live.recorder_process import RecorderProcess
    from estimator.live.runtime import LiveConfig, LiveEstimator, keys, run_live
    from estimator.live.zenoh_run import command_keys
    from tpods.cli.estimate_ekf import _filter_config

    structure = None
    if args.structure is not None:
        from common.layout_files import load_live_layout

        structure = load_live_layout(args.structure)
        if args.method == "ekf":
            opt = "--vehicle" if structure.kind == "vehicle" else "--structure"
            raise UserError(f"{opt} is estimated with --method ls-ekf only: from a "
                            f"{structure.kind}'s geometric start the EKF alone diverges "
                            "(docs/estimators.md)")
        args.method = "ls-ekf"
        if args.body is None:
            args.body = structure.name
        if args.thrust_table is not None:
            structure.check_table_option()
    args.method = args.method or "ekf"
    args.body = args.body or "tpods1"
    if args.method == "ls-ekf" and args.duration is not None and args.ls_window >= args.duration:
        raise UserError(f"--ls-window {args.ls_window:g} s is not shorter than --duration "
                        f"{args.duration:g} s: the LS start would never run; give --ls-window "
                        f"below {args.duration:g} s")
    is_vehicle = structure is not None and structure.kind == "vehicle"
    table = load_thrust_table(args.thrust_table)
    if structure is not None and args.thrust_table is not None:
        structure = structure.with_table(table)
    cfg = LiveConfig(method=args.method, ekf=_filter_config(args), ls_window_s=args.ls_window,
                     ls_start=args.ls_start, max_wait_s=args.max_wait_ms * 1e-3,
                     publish_rate_hz=args.rate, ls_in_process=True, rewind_s=args.rewind_s,
                     n_channels=structure.n_channels if is_vehicle else 4,
                     clock_offset_s=(args.clock_offset_ms if isinstance(args.clock_offset_ms, float)
                                     else 0.0) * 1e-3,
                     clock_offset_auto=args.clock_offset_ms == "auto")
    k = keys(args.body, args.mocap_prefix, args.prefix,
             [m.name for m in structure.modules] if structure is not None and not is_vehicle
             else None)
    rec = log = None
    if args.mcap and args.out is None:
        raise UserError("--mcap records into the --out folder; give --out RUN_DIR (or --out X.mcap)")
    if is_mcap(args.out):
        log = McapProcessLog(stream_file(args.out, force=args.force),
                      meta={"command": "tpods estimate live", "body": args.body, "keys": k})
    elif args.out is not None:
        folder = stream_folder(args.out, force=args.force, command="tpods estimate live")
        rec = RecorderProcess(folder, {
            "kind": "live-estimate", "software": f"tpods {tpods.__version__}",
            "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
            "body": args.body, "keys": k, "method": args.method,
            "thrust_table": args.thrust_table or "built-in Table 2",
            "settings": {"max_wait_s": cfg.max_wait_s, "rewind_s": cfg.rewind_s,
                         "clock_offset_s": cfg.clock_offset_s,
                         "clock_offset_auto": cfg.clock_offset_auto,
                         "publish_rate_hz": cfg.publish_rate_hz,
                         "ls_window_s": cfg.ls_window_s, "ls_start": cfg.ls_start,
                         "q_psd": list(cfg.ekf.q_psd), "sigma0": list(cfg.ekf.sigma0),
                         "sigma_meas": list(cfg.ekf.sigma_meas),
                         "underweight": cfg.ekf.underweight}},
            n_channels=structure.n_channels if structure is not None else 4, structure=structure)
        if args.mcap:
            log = McapProcessLog(Path(args.out) / "recording.mcap",
                          meta={"command": "tpods estimate live", "body": args.body, "keys": k})
    est = LiveEstimator(table, cfg, args.body, recorder=rec, structure=structure)
    est.on_note = lambda line: print(line, file=sys.stderr)
    if args.resume is not None:
        resumed = _resume(est, args)
        if rec is not None:
            rec.meta.update(resumed)
            rec.write_meta()
    console = _Console(args.quiet)
    stop = threading.Event()
    status = "failed"
    res = None
    subs = []
    try:
        with zenoh_session(args, stop) as session:
            try:
                if log is not None:
                    subs = record_streams(session, k, log)
                cmds = " + ".join(command_keys(k))
                print(f"live: {k['pose']} + {cmds} -> {k['estimate']} ({args.method}, "
                      f"thrust table {args.thrust_table or 'Table 2'})", file=sys.stderr)
                with PingPoller(session, clock_key(args.body, args.prefix)) as ping:
                    res = run_live(session, est, stop=stop, duration_s=args.duration,
                                   exit_on_end=args.exit_on_end, mocap_prefix=args.mocap_prefix,
                                   prefix=args.prefix, on_console=console.show,
                                   on_idle=tuple(r.idle for r in (rec, log) if r is not None))
                est.clock_ping = ping.summary()
                status = res.status
            finally:
                for s in subs:
                    s.undeclare()
    finally:
        console.end()
        summary = est.summary()
        if summary.get("mass_kg") is None:  # received nothing: no success (run.json says
            status = "failed"               # failed; the command exits 2, below)
        if log is not None:
            log.close(status)
        if rec is not None:
            rec.close(status, {"final": summary})
            write_json(Path(args.out) / "estimate.json", summary)
    c = summary["counters"]
    if summary.get("mass_kg") is None:  # received nothing (or no commands): say so, exit 2
        raise UserError(nothing_received(c, k, args.body))
    span = est.hist_t[-1] - est.hist_t[0] if est.hist_t else 0.0
    if args.method == "ls-ekf" and est.hist_t and "ls" not in summary and "ls_error" not in summary \
            and span < args.ls_window:
        print(f"tpods: warning: the LS start never ran: the poses span {span:.3g} s, less than "
              f"--ls-window {args.ls_window:g} s; the estimate is the plain EKF's", file=sys.stderr)
    if summary.get("diverged"):
        print("tpods: warning: the live filter diverged (non-physical mass or Izz, or innovations "
              "far larger than their covariance); do not use this estimate. Late commands: "
              f"{c['align_cmds_late']} not used, {c['align_cmds_rewound']} re-filtered; "
              "post-process the run with `tpods estimate batch`", file=sys.stderr)
    elif summary.get("inconsistent"):
        print("tpods: warning: the live filter's recent innovations are larger than its covariance "
              "allows (mean NIS above the chi-square bound): its sigma understates the error",
              file=sys.stderr)
    from estimator.live.gaps import gap_warnings

    for line in gap_warnings(est.gaps.rows(), est.aligner.first_command_t):  # never bridged silently
        print(f"tpods: warning: {line}", file=sys.stderr)
    from estimator.live.clock_report import clock_offset_lines

    valves = getattr(getattr(structure, "vehicle", None), "valves", None)
    info, warns = clock_offset_lines(summary, getattr(valves, "delay_sigma_s", None))
    for line in info:
        print(line, file=sys.stderr)
    for line in warns:
        print(f"tpods: warning: {line}", file=sys.stderr)
    if not summary.get("thrust_uncertainty", {}).get("included", True):
        print(f"tpods: warning: {summary['thrust_uncertainty']['note']}", file=sys.stderr)
    if args.json:
        sys.stdout.write(json.dumps(summary, default=str) + "\n")
        return 0
    print(f"live {status} ({summary['phase']}, {summary['n_updates']} updates)")
    print(f"  mass = {summary['mass_kg']:.6g} kg      +/- {summary['mass_sigma_kg']:.3g} (1 sigma)")
    print(f"  Izz  = {summary['izz_kgm2']:.6g} kg m^2  +/- {summary['izz_sigma_kgm2']:.3g} (1 sigma)"
          + (" about the centre of mass" if structure is not None else ""))
    if structure is not None:
        print(f"  centre of mass = ({summary['com_x_m']:.5f}, {summary['com_y_m']:.5f}) m "
              f"+/- ({summary['com_x_sigma_m']:.2g}, {summary['com_y_sigma_m']:.2g}) in the tracked "
              f"frame; Izz about the tracked origin {summary['izz_origin_kgm2']:.6g} kg m^2")
    for line in budget_lines(filter_budget(summary)):
        print(line)
    if "ls" in summary:
        ls = summary["ls"]
        print(f"  LS start on the first {ls['window_s']:g} s: mass {ls['mass_kg']:.6g} kg, "
              f"Izz {ls['izz_kgm2']:.6g} kg m^2 ({ls['elapsed_s']:.2f} s in the background)")
    if "ls_error" in summary:
        print(f"  LS start failed: {summary['ls_error']}")
    print(f"  poses {c['poses_rx']} received, {c['updates']} used; occluded {c['align_occluded']}, "
          f"duplicates {c['align_duplicates']}, too old {c['align_too_old']}, malformed "
          f"{c['malformed']}; commands {c['cmds_rx']}, late {c['align_cmds_late']} (re-filtered "
          f"{c['align_cmds_rewound']}); released by "
          f"timeout {c['align_released_by_timeout']}; largest backlog {c['max_backlog']}")
    if rec is not None:
        print(f"  wrote {args.out} (commands.csv, poses.csv, estimates.csv, run.json, estimate.json"
              + (", recording.mcap)" if log is not None else ")"))
    elif log is not None:
        print(f"  wrote {log.path} ({log.counters['messages']} messages)")
    if not math.isfinite(summary["mass_kg"]):
        raise UserError("the filter diverged (non-finite estimate)")
    return 0


def nothing_received(c: dict, k: dict, body: str) -> str:
    """The refusal of a live run that gave no estimate: what was missing and where to look."""
    from estimator.live.zenoh_run import command_keys

    cmds = " + ".join(command_keys(k))
    if c["poses_rx"] == 0:
        return (f"no estimate: received no poses on {k['pose']} ({c['cmds_rx']} commands on "
                f"{cmds}): is `tpods mocap bridge` running on the same Zenoh network "
                f"(--connect/--listen), for body {body!r} (--body, --mocap-prefix)?")
    return (f"no estimate: received {c['poses_rx']} poses and {c['cmds_rx']} commands on {cmds}, "
            "none the filter could pair (it needs the commands in time with the poses): is "
            f"`tpods run play` publishing for body {body!r} (--prefix), on the same clock?")


def _resume(est, args) -> dict:
    """``--resume RUN_DIR`` (:func:`estimator.live.resume.resume_from`), one stderr line."""
    from estimator.live.resume import resume_from

    if est.structure is not None:
        raise UserError("--resume takes a module's run (not a structure's or a vehicle's)")
    if args.out is not None and Path(args.out).resolve() == Path(args.resume).resolve():
        raise UserError("--resume RUN_DIR needs another --out folder (the dead run's stays as "
                        "it was)")
    r = resume_from(est, args.resume)
    print(f"live: resumed from {args.resume}: {r['replayed_commands']} commands, "
          f"{r['replayed_poses']} poses taken in", file=sys.stderr)
    return r
