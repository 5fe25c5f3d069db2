"""Fit a bench session folder: the use case behind ``tpods bench fit``, callable from a
notebook.

:func:`fit_session` fits a characterisation session (duty steps: thrust polynomials of
orders 1-4 per nozzle count, paper Eqs. 8-11; writes a thrust table TOML with its
uncertainty and two plots) or, for a session of on/off pulses (``tpods bench import``),
:func:`fit_pulse_session` (the steady force per valve and per count in N, each valve's
dead time and rise in s; writes pulse_fit.json and a plot). Each returns a
:class:`SessionFit` (the JSON document, the text report, the warnings, the files) and
prints nothing; a user error raises :class:`common.errors.UserError`.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

from bench.fit import fit_steps, max_error_pct_full_scale, table_uncertainty
from bench.pulse_fit import fit_pulses
from bench.session import read_session
from common.outputs import check_plain_folder, not_an_input, result_output
from common.plausible_inputs import loadcell_force_warning
from common.thrust_table import ThrustTable


@dataclass
class SessionFit:
    """A fitted session: ``doc`` (what ``--json`` prints), ``lines`` (the text report),
    ``warnings``."""

    doc: dict
    lines: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)


def is_pulse_session_folder(run_dir: str | Path) -> bool:
    """True when RUN_DIR's run.json says it holds on/off valve pulses (bench import)."""
    try:
        meta = json.loads((Path(run_dir) / "run.json").read_text())
    except (OSError, ValueError):
        return False
    return isinstance(meta, dict) and meta.get("valves") == "on/off"


def fit_session(run_dir: str | Path, *, order: str = "auto", criterion: str = "aicc",
                out: str | Path | None = None, force: bool = False,
                pressure_psi: float | None = None, balance_linearity_g: float | None = None,
                scale_rel: float = 0.0, plot_dir: str | Path | None = None,
                reference: str | None = None) -> SessionFit:
    """The thrust table of the session in ``run_dir``: ``order`` 1-4 or auto (chosen by
    ``criterion``: aicc, bic or cv), written to ``out`` (FILE.toml, or thrust_table.toml in
    a folder; default RUN_DIR/thrust_table.toml) with its plots (in ``plot_dir``, else
    beside it); ``reference``: a table to compare with (a TOML or 'table2'). A pulse
    session goes to :func:`fit_pulse_session`."""
    from bench.plots import plot_fit_orders, plot_time_series  # lazy: matplotlib

    if is_pulse_session_folder(run_dir):  # on/off valves (bench import): forces, delays, rises
        return fit_pulse_session(run_dir, out=out, force=force, scale_rel=scale_rel, ignored=[
            o for o, v in (("--order", order != "auto"), ("--reference", reference),
                           ("--pressure-psi", pressure_psi),
                           ("--balance-linearity-g", balance_linearity_g),
                           ("--plot-dir", plot_dir), ("--criterion", criterion != "aicc")) if v])
    # the --out rule: FILE.toml is the table; a folder receives thrust_table.toml and the plots
    out_file = result_output(Path(run_dir) / "thrust_table.toml" if out is None else out,
                             "thrust_table.toml", force=force, command="tpods bench fit")
    not_an_input(out_file, run_dir)
    check_plain_folder(None if plot_dir is None else str(plot_dir), "--plot-dir")
    path = out_file.main
    raw, steps = read_session(run_dir)
    steps_csv = Path(run_dir) / "steps.csv"
    from_file = steps_csv.is_file() and len(steps_csv.read_bytes().split(b"\n", 2)) > 2
    result = fit_steps(steps, order, criterion,  # a damaged cell names its line
                       source=str(steps_csv) if from_file else f"{run_dir}: steps from raw.csv",
                       path=str(steps_csv) if from_file else None)
    table = result.table(pressure_psi, source=f"tpods bench fit {run_dir}")
    readings = raw["reading_gf"].to_numpy(dtype=float) if "reading_gf" in raw else None
    unc = table_uncertainty(steps, readings, linearity_g=balance_linearity_g, extra_rel=scale_rel)
    table = dataclasses.replace(table, uncertainty=unc)
    ref = None
    if reference is not None:
        ref = ThrustTable.default() if reference.lower() == "table2" else ThrustTable.load(reference)
    in_folder = out_file.is_folder and not plot_dir  # a folder output holds its plots
    with out_file.writing_main() as (tmp, d):
        table.save(tmp)
        if in_folder:
            p1 = out_file.final(plot_fit_orders(result, d / f"{path.stem}_orders.png", truth=ref))
            p2 = out_file.final(plot_time_series(raw, d / f"{path.stem}_timeseries.png", steps))
    if not in_folder:
        folder = Path(plot_dir) if plot_dir else path.parent
        folder.mkdir(parents=True, exist_ok=True)
        p1 = plot_fit_orders(result, folder / f"{path.stem}_orders.png", truth=ref)
        p2 = plot_time_series(raw, folder / f"{path.stem}_timeseries.png", steps)
    doc = {"thrust_table": str(path), "plots": [str(p1), str(p2)],
           "selected_order": {str(k): n for k, n in result.selected.items()}, **table.extra}
    lines = [f"{'nozzles':>7} {'order':>5} {'rms_gf':>8} {'cv_rms_gf':>9} {'AICc':>8} {'BIC':>8}"]
    for k in sorted(result.fits):
        for n, f in sorted(result.fits[k].items()):
            mark = " <" if n == result.selected[k] else ""
            lines.append(f"{k:>7} {n:>5} {f.rms:>8.3f} {f.cv_rms:>9.3f} {f.aicc:>8.2f} {f.bic:>8.2f}{mark}")
    if ref is not None:
        errs = max_error_pct_full_scale(table, ref)
        lines.append("max |fit - reference| over 10-90 %, % of full scale: "
                     + ", ".join(f"{k} nozzle(s) {v:.2f}" for k, v in errs.items()))
    lines += [f"table uncertainty: coefficient covariance of each fit (statistical) and "
              f"scale_rel = {unc.scale_rel:.2%}: {unc.sources['scale_rel']}",
              f"wrote {path}, {p1}, {p2}"]
    return SessionFit(doc, lines)


def fit_pulse_session(run_dir: str | Path, *, out: str | Path | None = None, force: bool = False,
                      scale_rel: float = 0.0, ignored: list[str] | None = None) -> SessionFit:
    """The on/off pulses of the session in ``run_dir``: steady force per valve and per
    count (N), dead time, rise, close delay and fall per valve (s), written to ``out``
    (FILE.json, or pulse_fit.json in a folder; default RUN_DIR/pulse_fit.json) with a plot
    of the edges; ``ignored``: options given that do not apply (said in the warnings)."""
    from bench.pulse_plots import plot_pulse_edges  # lazy: matplotlib

    default = Path(run_dir) / "pulse_fit.json"
    dest = result_output(default if out is None else out, "pulse_fit.json", force=force,
                         command="tpods bench fit (on/off pulses)")
    not_an_input(dest, run_dir)
    raw, steps = read_session(run_dir)
    res = fit_pulses(raw, steps, scale_rel=scale_rel)
    warnings = list(res.warnings) + ([f"{', '.join(ignored)}: not used for on/off pulses"]
                                     if ignored else []) + _force_unit_warnings(run_dir, res)
    doc = {**res.to_dict(), "warnings": warnings, "session": str(run_dir),
           "vehicle_valves": vehicle_valves(res)}
    with dest.writing_main() as (main, d):
        main.write_text(json.dumps(doc, indent=2, default=float) + "\n")
        plot = dest.final(plot_pulse_edges(raw, res, (d or main.parent) / f"{dest.main.stem}_edges.png"))
    lines = [f"{'valve':>5} {'force N':>9} {'sigma':>8} {'delay ms':>9} {'sigma':>6} {'rise ms':>8} "
             f"{'sigma':>6} {'close ms':>9} {'fall ms':>8} {'pulses':>6}"]

    def ms(v):
        return "-" if v is None or not math.isfinite(v) else f"{v * 1e3:.0f}"

    for v, r in sorted(res.valves.items()):
        lines.append(f"{v:>5} {r['force_n']:>9.4f} {r['force_sigma_n']:>8.2g} {ms(r['delay_s']):>9} "
                     f"{ms(r['delay_sigma_s']):>6} {ms(r['rise_s']):>8} {ms(r['rise_sigma_s']):>6} "
                     f"{ms(r['close_delay_s']):>9} {ms(r['fall_s']):>8} {r['n_pulses']:>6}")
    lines += [f"  {k} valve(s) open: {r['force_n']:.4f} +- {r['force_sigma_n']:.2g} N per valve set "
              f"({r['n_pulses']} pulses; {'; '.join(r['valve_sets'])})" for k, r in sorted(res.counts.items())]
    vv = doc["vehicle_valves"]
    if vv:
        lines.append(f"for the vehicle file: [valves] delay_s = {vv['delay_s']:.3g}  # +- "
                     f"{vv['delay_sigma_s']:.2g}; rise_s = {vv['rise_s']:.3g}  # +- {vv['rise_sigma_s']:.2g}")
    lines.append(f"wrote {dest.main}, {plot}")
    return SessionFit(doc, lines, warnings)


def vehicle_valves(res) -> dict | None:
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
