"""``tpods bench import`` (load-cell CSV logs as a thrust session) and the on/off pulse half
of ``tpods bench fit`` (steady force per valve and per count, dead time and rise): thin shell
over :mod:`bench.loadcell_import` and :mod:`bench.pulse_fit`."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from common.argtypes import nonneg_float
from common.errors import UserError
from common.outputs import ResultFolder, add_force, result_output
from tpods.cli.parser import command


def register_import(g) -> None:
    """Add ``import`` to the ``bench`` group."""
    p = command(
        g, "import", cmd_import,
        help="a load-cell CSV log (HX711 and the like) as a session bench fit reads")
    p.add_argument("file", metavar="FILE", help="the log (CSV, or tab-separated)")
    p.add_argument("--out", required=True, metavar="SESSION", help="session folder to write")
    p.add_argument("--columns", default=None, metavar="t=COL,force=COL,valves=COL[,phase=COL]",
                   help="the log's column names (default t=t_s,force=weight_g,valves=bitmask,"
                        "phase=phase; the phase column is optional)")
    p.add_argument("--force-unit", default="g", choices=("g", "gf", "kg", "kgf", "N", "mN"),
                   help="unit of the force column; a mass reading (g, kg) is taken as gram- or "
                        "kilogram-force (default g)")
    p.add_argument("--valves-as", default="bitmask", choices=("bitmask", "vector", "duty"),
                   help="bitmask: integer, bit i = valve i+1 open (default); vector: 0/1 per "
                        "valve ('[1, 0, 1, 0]'); duty: percent, one number (valve 1) or one per valve")
    p.add_argument("--time-unit", default="s", choices=("s", "ms"), help="default s")
    p.add_argument("--settle", type=nonneg_float, default=1.0, metavar="S",
                   help="readings after a valve opens left out of its steady force, s (default 1)")
    p.add_argument("--zero-settle", type=nonneg_float, default=1.0, metavar="S",
                   help="readings after the valves close left out of the zero, s (default 1)")
    add_force(p)


def cmd_import(args: argparse.Namespace) -> int:
    """Read a CSV log of another thrust bench (time, force or mass reading, valve state, optional
    phase) into a session folder (raw.csv, steps.csv, run.json) that `tpods bench fit` fits:
    on/off pulses (force per valve and per count, dead time and rise) or duty steps (polynomials
    per nozzle count). Rows are cut where the valve state changes; empty force cells and tare
    phases are skipped and counted."""

    from bench.loadcell_import import parse_columns, read_log, session_meta
    from bench.session import summarize_steps
    from common.runwriter import run_header, write_json_atomic

    out = ResultFolder(args.out, force=args.force, command="tpods bench import")
    log = read_log(args.file, parse_columns(args.columns), args.force_unit, args.valves_as,
                   args.time_unit, args.settle, args.zero_settle)
    steps = summarize_steps(log.raw)
    if steps.empty:
        raise UserError(f"{args.file}: no valve stayed open past --settle {args.settle:g} s: "
                        "no step to fit")
    options = {"columns": args.columns, "force_unit": args.force_unit, "valves_as": args.valves_as,
               "time_unit": args.time_unit, "settle_s": args.settle, "zero_settle_s": args.zero_settle}
    meta = run_header("thrust-characterisation", **session_meta(log, str(args.file), options))
    with out.writing() as d:
        log.raw.to_csv(d / "raw.csv", index=False, float_format="%.10g")
        steps.to_csv(d / "steps.csv", index=False)
        write_json_atomic(d / "run.json", meta)
    c = log.counts
    kind = "on/off pulses" if log.on_off else "duty steps"
    print(f"imported {c['readings']} readings of {log.n_valves} valve(s) as {kind}: "
          f"{len(steps)} steps; {c['empty_force_cells']} empty force cell(s) and "
          f"{c['tare_rows_skipped']} tare row(s) skipped")
    print(f"wrote {out.path}/raw.csv, steps.csv, run.json (fit it: tpods bench fit {out.path})")
    return 0


def pulse_session(run_dir: str) -> bool:
    """True when RUN_DIR's run.json says it holds on/off valve pulses (bench import)."""
    try:
        meta = json.loads((Path(run_dir) / "run.json").read_text())
    except (OSError, ValueError):
        return False
    return isinstance(meta, dict) and meta.get("valves") == "on/off"


def cmd_fit_pulses(args: argparse.Namespace) -> int:
    """``bench fit`` on an on/off pulse session."""
    from bench.pulse_fit import fit_pulses
    from bench.pulse_plots import plot_pulse_edges
    from bench.session import read_session
    from common.outputs import not_an_input

    default = Path(args.run_dir) / "pulse_fit.json"
    out = result_output(default if args.out is None else args.out, "pulse_fit.json",
                        force=args.force, command="tpods bench fit (on/off pulses)")
    not_an_input(out, args.run_dir)
    raw, steps = read_session(args.run_dir)
    res = fit_pulses(raw, steps, scale_rel=args.scale_rel)
    ignored = [o for o, v in (("--order", args.order != "auto"), ("--reference", args.reference),
                              ("--pressure-psi", args.pressure_psi),
                              ("--balance-linearity-g", args.balance_linearity_g),
                              ("--plot-dir", args.plot_dir), ("--criterion", args.criterion != "aicc")) if v]
    warnings = list(res.warnings) + ([f"{', '.join(ignored)}: not used for on/off pulses"]
                                     if ignored else []) + _force_unit_warnings(args.run_dir, res)
    doc = {**res.to_dict(), "warnings": warnings, "session": str(args.run_dir),
           "vehicle_valves": _vehicle_valves(res)}
    with out.writing_main() as (main, d):
        main.write_text(json.dumps(doc, indent=2, default=float) + "\n")
        plot = out.final(plot_pulse_edges(raw, res, (d or main.parent) / f"{out.main.stem}_edges.png"))
    for w in warnings:
        print(f"tpods: warning: {w}", file=sys.stderr)
    if args.json:
        json.dump(doc, sys.stdout, indent=2, default=float)
        sys.stdout.write("\n")
        return 0
    print(f"{'valve':>5} {'force N':>9} {'sigma':>8} {'delay ms':>9} {'sigma':>6} {'rise ms':>8} "
          f"{'sigma':>6} {'close ms':>9} {'fall ms':>8} {'pulses':>6}")

    def ms(v):
        return "-" if v is None or not math.isfinite(v) else f"{v * 1e3:.0f}"

    for v, r in sorted(res.valves.items()):
        print(f"{v:>5} {r['force_n']:>9.4f} {r['force_sigma_n']:>8.2g} {ms(r['delay_s']):>9} "
              f"{ms(r['delay_sigma_s']):>6} {ms(r['rise_s']):>8} {ms(r['rise_sigma_s']):>6} "
              f"{ms(r['close_delay_s']):>9} {ms(r['fall_s']):>8} {r['n_pulses']:>6}")
    for k, r in sorted(res.counts.items()):
        print(f"  {k} valve(s) open: {r['force_n']:.4f} +- {r['force_sigma_n']:.2g} N per valve set "
              f"({r['n_pulses']} pulses; {'; '.join(r['valve_sets'])})")
    vv = doc["vehicle_valves"]
    if vv:
        print(f"for the vehicle file: [valves] delay_s = {vv['delay_s']:.3g}  # +- "
              f"{vv['delay_sigma_s']:.2g}; rise_s = {vv['rise_s']:.3g}  # +- {vv['rise_sigma_s']:.2g}")
    print(f"wrote {out.main}, {plot}")
    return 0


def _vehicle_valves(res) -> dict | None:
    """Mean delay and rise over the valves (the vehicle file's ``[valves]``), with sigmas."""
    rows = [r for r in res.valves.values() if r.get("delay_s") is not None]
    if not rows:
        return None
    n = len(rows)

    def mean_sigma(k):
        vals = [r[k] for r in rows]
        sig = math.sqrt(sum(r[f"{k[:-2]}_sigma_s"] ** 2 for r in rows)) / n
        spread = (sum((x - sum(vals) / n) ** 2 for x in vals) / (n - 1)) ** 0.5 / math.sqrt(n) if n > 2 else 0.0
        return sum(vals) / n, max(sig, spread)

    d, sd = mean_sigma("delay_s")
    r, sr = mean_sigma("rise_s")
    return {"delay_s": d, "delay_sigma_s": sd, "rise_s": r, "rise_sigma_s": sr, "n_valves": n}


def _force_unit_warnings(run_dir, res) -> list[str]:
    """A force per valve no air-table thruster gives, with the --force-unit that would fit
    (:func:`common.plausible_inputs.loadcell_force_warning`)."""
    from common.plausible_inputs import loadcell_force_warning

    try:
        meta = json.loads((Path(run_dir) / "run.json").read_text())
        unit = meta.get("import", {}).get("force_unit") or meta.get("options", {}).get("force_unit")
    except (OSError, ValueError, AttributeError):
        unit = None
    out = []
    for v, r in sorted(res.valves.items()):
        w = loadcell_force_warning(float(r["force_n"]), unit, f"valve {v}")
        if w:
            out.append(w)
    return out
