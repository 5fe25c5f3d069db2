"""``tpods bench``: thrust characterisation (characterize, fit) and device emulators."""

from __future__ import annotations

import argparse
import json
import sys
import threading
from pathlib import Path

from common.argtypes import nonneg_float, positive_float
from common.errors import UserError
from common.outputs import add_force, not_an_input, optional_folder, result_output, stream_folder
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


def _serial_format(text: str) -> dict:
    t = text.strip().upper()
    if len(t) != 3 or t[0] not in "5678" or t[1] not in "NEOMS" or t[2] not in "12":
        raise UserError(f"serial format must look like 8N1 or 7E1, got {text!r}")
    return {"bytesize": int(t[0]), "parity": t[1], "stopbits": int(t[2])}


MAX_VALVES = 4
"""Valves of a TPODS module's controller (the session checks the device's own count too)."""

SESSION_FILES = ("raw.csv", "steps.csv", "run.json", "valves.serial.jsonl", "scale.serial.jsonl")


def _replace_empty_failed_session(out: str | Path | None) -> None:
    """A session that failed before its first reading (a device that does not answer, an
    option the controller refuses) holds nothing to keep but its run.json, which says why.
    Re-running into the same --out replaces it without --force, saying so on stderr."""
    if not out:
        return
    out = Path(out)
    try:
        names = {p.name for p in out.iterdir()}
        meta = json.loads((out / "run.json").read_text())
        with (out / "raw.csv").open() as fh:
            has_data = sum(1 for _ in zip(range(2), fh, strict=False)) > 1
    except (OSError, ValueError):
        return
    if not names <= set(SESSION_FILES) or has_data or not isinstance(meta, dict) \
            or meta.get("status") != "failed":
        return
    for name in SESSION_FILES:
        (out / name).unlink(missing_ok=True)
    print(f"tpods: replacing {out}: a failed session without readings "
          f"({str(meta.get('error') or '')[:80]})", file=sys.stderr)


def cmd_characterize(args: argparse.Namespace) -> int:
    from bench.capture import capture_folder
    from bench.ohaus.driver import OhausScout
    from bench.session import (
        SessionConfig,
        Terminated,
        parse_duty_steps,
        parse_int_list,
        run_session,
        sigterm_raises,
    )
    from bench.valves import ValveController
    from tpods.cli.options import DEFAULT_DUTY_LIMITS

    args.duty_limits = args.duty_limits or DEFAULT_DUTY_LIMITS
    lim = parse_duty_steps(args.duty_limits.replace(":", ","))
    if len(lim) != 2:
        raise UserError(f"--duty-limits must be LOW,HIGH, got {args.duty_limits!r}")
    cfg = SessionConfig(
        nozzles=parse_int_list(args.nozzles, "--nozzles"), duties_pct=parse_duty_steps(args.duty),
        dwell_s=args.dwell, settle_s=args.settle, zero_settle_s=args.zero_settle,
        zero_dwell_s=args.zero_dwell, zero_every=args.zero_every, pwm_hz=args.pwm_hz,
        nozzle_under_test=args.nozzle_under_test, duty_limits_pct=(lim[0], lim[1]),
        watchdog_ms=args.watchdog_ms)
    if not 1 <= cfg.pwm_hz <= 100:
        raise UserError(f"--pwm-hz must be 1-100, got {cfg.pwm_hz:g}")
    if max(cfg.nozzles) > MAX_VALVES:
        raise UserError(f"--nozzles {args.nozzles}: a TPODS module has {MAX_VALVES} valves; "
                        f"cannot open {max(cfg.nozzles)} at once")
    fmt = _serial_format(args.scale_format)
    _replace_empty_failed_session(args.out)
    cap_dir = None if args.capture in (None, True) else capture_folder(args.capture, args.force, "tpods bench characterize")
    out = stream_folder(args.out, force=args.force, command="tpods bench characterize")
    if args.capture is True:
        cap_dir = Path(out)
    hs = args.scale_handshake
    with sigterm_raises():
        try:
            with ValveController(args.valves, baudrate=args.valves_baud, duty_limits=cfg.duty_limits_pct,
                                 capture=cap_dir and cap_dir / "valves.serial.jsonl") as valves, \
                 OhausScout(args.scale, baudrate=args.scale_baud, xonxoff=hs == "xonxoff",
                            rtscts=hs == "rtscts", silence_timeout=args.silence_timeout,
                            acquisition=args.scale_mode, poll_interval_s=args.scale_poll_interval,
                            capture=cap_dir and cap_dir / "scale.serial.jsonl", **fmt) as scale:
                res = run_session(valves, scale, cfg, out, progress=not args.no_progress)
        except (Terminated, KeyboardInterrupt) as exc:
            return valves_closed_exit(exc, f"valves closed; partial data in {out}")
    print(f"session {res.status}: {len(res.steps)} steps, {res.n_readings} readings, "
          f"{res.n_garbage} garbage line(s) skipped")
    print(f"time {res.elapsed_s:.1f} s for {res.planned_s:.1f} s planned "
          f"(overhead {res.overhead_pct:+.1f} %)")
    print(f"wrote {out}/raw.csv, steps.csv, run.json")
    if cap_dir is not None:
        print(f"wrote {cap_dir}/valves.serial.jsonl, scale.serial.jsonl (serial transcripts)")
    return 0



def cmd_fit(args: argparse.Namespace) -> int:
    import dataclasses

    from bench.fit import fit_steps, max_error_pct_full_scale, table_uncertainty
    from bench.plots import plot_fit_orders, plot_time_series
    from bench.session import read_session
    from common.outputs import check_plain_folder
    from common.thrust_table import ThrustTable
    from tpods.cli.bench_loadcell import cmd_fit_pulses, pulse_session

    if pulse_session(args.run_dir):  # on/off valves (bench import): forces, delays, rises
        return cmd_fit_pulses(args)
    # the --out rule: FILE.toml is the table; a folder receives thrust_table.toml and the plots
    out_file = result_output(Path(args.run_dir) / "thrust_table.toml" if args.out is None else args.out,
                             "thrust_table.toml", force=args.force, command="tpods bench fit")
    not_an_input(out_file, args.run_dir)
    check_plain_folder(args.plot_dir, "--plot-dir")
    out = out_file.main
    raw, steps = read_session(args.run_dir)
    steps_csv = Path(args.run_dir) / "steps.csv"
    from_file = steps_csv.is_file() and len(steps_csv.read_bytes().split(b"\n", 2)) > 2
    result = fit_steps(steps, args.order, args.criterion,  # a damaged cell names its line
                       source=str(steps_csv) if from_file else f"{args.run_dir}: steps from raw.csv",
                       path=str(steps_csv) if from_file else None)
    table = result.table(args.pressure_psi, source=f"tpods bench fit {args.run_dir}")
    readings = raw["reading_gf"].to_numpy(dtype=float) if "reading_gf" in raw else None
    unc = table_uncertainty(steps, readings, linearity_g=args.balance_linearity_g,
                            extra_rel=args.scale_rel)
    table = dataclasses.replace(table, uncertainty=unc)
    reference = None
    if args.reference is not None:
        reference = ThrustTable.default() if args.reference.lower() == "table2" else ThrustTable.load(args.reference)
    in_folder = out_file.is_folder and not args.plot_dir  # a folder output holds its plots
    with out_file.writing_main() as (tmp, d):
        table.save(tmp)
        if in_folder:
            p1 = out_file.final(plot_fit_orders(result, d / f"{out.stem}_orders.png", truth=reference))
            p2 = out_file.final(plot_time_series(raw, d / f"{out.stem}_timeseries.png", steps))
    if not in_folder:
        plot_dir = Path(args.plot_dir) if args.plot_dir else out.parent
        plot_dir.mkdir(parents=True, exist_ok=True)
        p1 = plot_fit_orders(result, plot_dir / f"{out.stem}_orders.png", truth=reference)
        p2 = plot_time_series(raw, plot_dir / f"{out.stem}_timeseries.png", steps)
    if args.json:
        json.dump({"thrust_table": str(out), "plots": [str(p1), str(p2)],
                   "selected_order": {str(k): n for k, n in result.selected.items()},
                   **table.extra}, sys.stdout, indent=2, default=float)
        sys.stdout.write("\n")
        return 0
    hdr = f"{'nozzles':>7} {'order':>5} {'rms_gf':>8} {'cv_rms_gf':>9} {'AICc':>8} {'BIC':>8}"
    print(hdr)
    for k in sorted(result.fits):
        for n, f in sorted(result.fits[k].items()):
            mark = " <" if n == result.selected[k] else ""
            print(f"{k:>7} {n:>5} {f.rms:>8.3f} {f.cv_rms:>9.3f} {f.aicc:>8.2f} {f.bic:>8.2f}{mark}")
    if reference is not None:
        errs = max_error_pct_full_scale(table, reference)
        print("max |fit - reference| over 10-90 %, % of full scale: "
              + ", ".join(f"{k} nozzle(s) {v:.2f}" for k, v in errs.items()))
    print(f"table uncertainty: coefficient covariance of each fit (statistical) and "
          f"scale_rel = {unc.scale_rel:.2%}: {unc.sources['scale_rel']}")
    print(f"wrote {out}, {p1}, {p2}")
    return 0


def cmd_emulate(args: argparse.Namespace) -> int:
    from bench.emulators import EmulatedScout, EmulatedValveController, serve_pty
    from common.thrust_table import load_thrust_table

    log_dir = optional_folder(args.log_dir, force=args.force, option="--log-dir",
                              command="tpods bench emulate")
    table = load_thrust_table(args.table)
    if args.channels < 1:
        raise UserError("--channels must be at least 1")
    if not 1 <= args.nozzle_under_test <= args.channels:
        raise UserError(f"--nozzle-under-test must be 1-{args.channels}")
    for name in ("unstable_prob", "garbage_prob"):
        if getattr(args, name) > 1:
            raise UserError(f"--{name.replace('_', '-')} must be a probability (0-1)")
    valves = EmulatedValveController(args.channels)
    scout = EmulatedScout(valves, table, args.nozzle_under_test, load_g=args.load_g, lag_s=args.lag_s,
                          noise_g=args.noise_g, drift_g_per_s=args.drift_g_per_s,
                          unstable_prob=args.unstable_prob, garbage_prob=args.garbage_prob,
                          print_rate_hz=args.rate_hz, seed=args.seed,
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
            with (d / "valves_log.csv").open("w") as fh:
                fh.write("t_s,cause," + ",".join(f"d{i + 1}" for i in range(args.channels)) + "\n")
                for ch in valves.log:
                    fh.write(f"{ch.t:.6f},{ch.cause}," + ",".join(f"{x:g}" for x in ch.duties) + "\n")
            with (d / "scale_sent.csv").open("w") as fh:
                fh.write("t_s,kind,line\n")
                for s in scout.sent:
                    fh.write(f"{s.t:.6f},{s.kind},{s.data.strip()!r}\n")
    print(f"stopped: {len(valves.log) - 1} valve change(s), {valves.watchdog_trips} watchdog trip(s), "
          f"{sum(s.kind == 'weight' for s in scout.sent)} reading(s) sent", file=sys.stderr)
    return 0
