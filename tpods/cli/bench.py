"""``tpods bench``: thrust characterisation (characterize, fit) and device emulators."""

from __future__ import annotations

import argparse
import json
import sys
import threading

from common.argtypes import nonneg_float, positive_float
from common.outputs import add_force, optional_folder
from tpods.cli.options import add_duty_limits, add_no_progress, add_random_seed, add_watchdog_ms
from tpods.cli.parser import group
from tpods.cli.stopping import stop_on_signals, valves_closed_exit


def register(sub) -> None:
    """Add this package's commands to the `tpods` parser."""
    g = group(sub, "bench", "thrust characterisation bench: valve controller + OHAUS balance")

    p = g.add_parser("characterize", help="run a thrust characterisation session",
                     description="Step the PWM duty of 1..k valves and record the thrust of the nozzle "
                                 "under test on an OHAUS balance. Writes raw.csv, steps.csv, run.json. "
                                 "The valves close (OFF confirmed by STATE?) on every exit path and the "
                                 "controller watchdog closes them if this process dies.")
    p.add_argument("--valves", required=True, metavar="URL",
                   help="valve controller: device path or pyserial URL (socket://HOST:PORT, ...)")
    p.add_argument("--scale", required=True, metavar="URL", help="OHAUS balance: device path or pyserial URL")
    p.add_argument("--nozzles", default="1,2,3,4", help="numbers of simultaneously open valves (default 1,2,3,4)")
    p.add_argument("--duty", default="10:90:10", help="duty steps, START:STOP:STEP or a list, %% (default 10:90:10)")
    p.add_argument("--dwell", type=positive_float, default=5.0, help="recorded time per step, s (default 5)")
    p.add_argument("--settle", type=nonneg_float, default=1.0, help="discarded time after opening, s (default 1)")
    p.add_argument("--zero-settle", type=nonneg_float, default=2.0,
                   help="discarded time after closing before a zero measurement, s (default 2)")
    p.add_argument("--zero-dwell", type=positive_float, default=1.0, help="zero measurement time, s (default 1)")
    p.add_argument("--zero-every", type=int, default=1, help="measure the zero after every N steps (default 1)")
    p.add_argument("--pwm-hz", type=positive_float, default=10.0, help="PWM frequency, Hz (default 10)")
    p.add_argument("--nozzle-under-test", type=int, default=1, help="valve channel on the balance (default 1)")
    add_duty_limits(p)
    add_watchdog_ms(p)
    p.add_argument("--valves-baud", type=int, default=115200, help="valve controller baud rate (default 115200)")
    p.add_argument("--scale-baud", type=int, default=9600, help="balance baud rate (default 9600)")
    p.add_argument("--scale-format", default="8N1", help="balance data bits, parity, stop bits (default 8N1; Scout Pro USB: 7N1)")
    p.add_argument("--scale-handshake", choices=("none", "xonxoff", "rtscts"), default="none")
    p.add_argument("--silence-timeout", type=positive_float, default=2.0,
                   help="no reading from the balance for this long aborts the session, s (default 2)")
    p.add_argument("--scale-mode", choices=("auto", "continuous", "poll"), default="auto",
                   help="balance acquisition: continuous print (CP), polling (IP per reading), or auto: "
                        "CP, polling if the balance refuses it (default auto)")
    p.add_argument("--scale-poll-interval", type=nonneg_float, default=0.1, metavar="S",
                   help="when polling, minimum time between two IP, s (default 0.1: a Scout "
                        "updates its reading about 10 times a second, and polling faster returns "
                        "the same reading again, which would shrink the step's standard error; "
                        "0: as fast as the balance answers)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--capture", nargs="?", const=True, default=None, metavar="DIR",
                   help="record byte-exact transcripts of both serial links (valves.serial.jsonl, "
                        "scale.serial.jsonl; docs/recordings.md) into the run folder, or into DIR; "
                        "replay them with --valves replay://PATH --scale replay://PATH")
    add_force(p)
    add_no_progress(p)
    p.set_defaults(func=cmd_characterize)
    from tpods.cli.bench_loadcell import register_import

    register_import(g)

    f = g.add_parser("fit", help="fit thrust polynomials to a characterisation run (or on/off pulses)",
                     description="Least squares (paper Eqs. 8-11) of orders 1-4 per nozzle count; writes a "
                                 "thrust table TOML with fit statistics and two plots. A session of "
                                 "on/off pulses (tpods bench import) gives the steady force per valve "
                                 "and per count, and each valve's dead time and rise "
                                 "(pulse_fit.json; docs/loadcell.md).")
    f.add_argument("run_dir", metavar="RUN_DIR",
                   help="folder written by `tpods bench characterize` or `tpods bench import`")
    f.add_argument("--order", default="auto", choices=("auto", "1", "2", "3", "4"),
                   help="polynomial order, or auto (pick by --criterion; default)")
    f.add_argument("--criterion", default="aicc", choices=("aicc", "bic", "cv"),
                   help="order selection: AICc (default), BIC or leave-one-step-out CV")
    f.add_argument("--out", default=None, metavar="FILE.toml|DIR",
                   help="thrust table to write: FILE.toml, or thrust_table.toml in folder DIR "
                        "(default RUN_DIR/thrust_table.toml); on/off pulses: FILE.json or DIR "
                        "(default RUN_DIR/pulse_fit.json)")
    add_force(f, "--out")
    f.add_argument("--json", action="store_true", help="print one JSON object (the fit) on stdout")
    f.add_argument("--pressure-psi", type=positive_float, default=None, help="accumulator pressure to record")
    f.add_argument("--balance-linearity-g", type=positive_float, default=None, metavar="G",
                   help="the balance's linearity, +/- g (default: 2 x its readability, read from "
                        "the session: the OHAUS Scout spec)")
    f.add_argument("--scale-rel", type=nonneg_float, default=0.0, metavar="R",
                   help="other relative 1-sigma scale errors the session cannot measure: "
                        "pressure set-point, PWM frequency (default 0, reported as not included)")
    f.add_argument("--plot-dir", default=None, help="where the PNG plots go (default: next to --out)")
    f.add_argument("--reference", default=None,
                   help="thrust table to compare with (a TOML path, or 'table2' for the paper's Table 2)")
    f.set_defaults(func=cmd_fit)

    e = g.add_parser("emulate", help="serve an emulated valve controller and OHAUS balance on ptys",
                     description="Serve an emulated protocol-v1 valve controller and an emulated OHAUS "
                                 "Scout (weighing the nozzle under test) on pseudo-terminals and print "
                                 "their device paths; runs until Ctrl-C or --duration.")
    e.add_argument("--channels", type=int, default=4, help="number of valves (default 4)")
    e.add_argument("--nozzle-under-test", type=int, default=1, help="valve whose thrust the balance feels")
    e.add_argument("--table", default=None, help="truth thrust table TOML (default the paper's Table 2)")
    e.add_argument("--load-g", type=float, default=0.0, help="static mass on the pan, g (default 0)")
    e.add_argument("--lag-s", type=nonneg_float, default=0.3, help="first-order lag, s (default 0.3)")
    e.add_argument("--noise-g", type=nonneg_float, default=0.2, help="reading noise std, g (default 0.2)")
    e.add_argument("--drift-g-per-s", type=float, default=0.003, help="zero drift, g/s (default 0.003)")
    e.add_argument("--unstable-prob", type=nonneg_float, default=0.03, help="random unstable flags (default 0.03)")
    e.add_argument("--garbage-prob", type=nonneg_float, default=0.01, help="garbage line probability (default 0.01)")
    e.add_argument("--rate-hz", type=positive_float, default=10.0, help="continuous print rate, Hz (default 10)")
    e.add_argument("--no-continuous-print", action="store_true",
                   help="the balance refuses CP with ES (continuous print disabled in its menu)")
    e.add_argument("--scale-baud", type=positive_float, default=None,
                   help="pace the balance's pty like an 8N1 serial line at this baud rate "
                        "(default: no pacing; a Scout runs at 9600)")
    add_random_seed(e)
    e.add_argument("--duration", type=positive_float, default=None, help="stop after this many seconds")
    e.add_argument("--log-dir", default=None, help="on exit write valves_log.csv and scale_sent.csv here")
    add_force(e, "--log-dir")
    e.set_defaults(func=cmd_emulate)


def cmd_characterize(args: argparse.Namespace) -> int:
    from bench.characterize import plan_characterize, run_characterize, session_lines
    from bench.session import Terminated, sigterm_raises
    from common.constants import DEFAULT_DUTY_LIMITS

    plan = plan_characterize(
        args.out, nozzles=args.nozzles, duty=args.duty, dwell=args.dwell, settle=args.settle,
        zero_settle=args.zero_settle, zero_dwell=args.zero_dwell, zero_every=args.zero_every,
        pwm_hz=args.pwm_hz, nozzle_under_test=args.nozzle_under_test,
        duty_limits=args.duty_limits or DEFAULT_DUTY_LIMITS, watchdog_ms=args.watchdog_ms,
        scale_format=args.scale_format, capture=args.capture, force=args.force,
        on_note=lambda note: print(note, file=sys.stderr))
    with sigterm_raises():
        try:
            res = run_characterize(
                plan, args.valves, args.scale, valves_baud=args.valves_baud,
                scale_baud=args.scale_baud, scale_handshake=args.scale_handshake,
                silence_timeout=args.silence_timeout, scale_mode=args.scale_mode,
                scale_poll_interval=args.scale_poll_interval, progress=not args.no_progress)
        except (Terminated, KeyboardInterrupt) as exc:
            return valves_closed_exit(exc, f"valves closed; partial data in {plan.out}")
    print("\n".join(session_lines(res, plan)))
    return 0


def cmd_fit(args: argparse.Namespace) -> int:
    from bench.session_fit import fit_session

    fit = fit_session(args.run_dir, order=args.order, criterion=args.criterion, out=args.out,
                      force=args.force, pressure_psi=args.pressure_psi,
                      balance_linearity_g=args.balance_linearity_g, scale_rel=args.scale_rel,
                      plot_dir=args.plot_dir, reference=args.reference)
    for w in fit.warnings:
        print(f"tpods: warning: {w}", file=sys.stderr)
    if args.json:
        json.dump(fit.doc, sys.stdout, indent=2, default=float)
        sys.stdout.write("\n")
        return 0
    print("\n".join(fit.lines))
    return 0


def cmd_emulate(args: argparse.Namespace) -> int:
    from bench.emulators import serve_pty
    from bench.emulators.pair import emulated_bench, stopped_line, write_logs

    log_dir = optional_folder(args.log_dir, force=args.force, option="--log-dir",
                              command="tpods bench emulate")
    valves, scout = emulated_bench(
        args.channels, args.nozzle_under_test, args.table, load_g=args.load_g, lag_s=args.lag_s,
        noise_g=args.noise_g, drift_g_per_s=args.drift_g_per_s, unstable_prob=args.unstable_prob,
        garbage_prob=args.garbage_prob, rate_hz=args.rate_hz, seed=args.seed,
        continuous_print=not args.no_continuous_print)
    stop = threading.Event()
    sv = serve_pty(valves)
    ss = serve_pty(scout, baud=args.scale_baud)
    try:
        with stop_on_signals(stop):  # until --duration, Ctrl-C or SIGTERM
            print(f"valves: {sv.path}")
            print(f"scale: {ss.path}", flush=True)
            print("serving; Ctrl-C to stop", file=sys.stderr, flush=True)
            stop.wait(args.duration)
    finally:
        ss.stop()
        sv.stop()
    if log_dir is not None:
        with log_dir.writing() as d:
            write_logs(d, valves, scout)
    print(stopped_line(valves, scout), file=sys.stderr)
    return 0
