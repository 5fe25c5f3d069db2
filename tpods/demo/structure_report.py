"""What ``tpods demo --structure`` (see :mod:`tpods.demo.structure`) writes at the end: the
summary table (truth, parts ground truth, live, batch: mass, Izz about the centre of mass,
cx, cy, each with its sigma and its error in sigmas), the figure of the structure
(:func:`estimator.reports.plots.structure.plot_structure`), ``report.md`` and ``summary.json``.
"""

from __future__ import annotations

import datetime as _dt
import json
from pathlib import Path
from typing import Any

from estimator.reports.plots.structure import ComPoint, plot_structure, plot_structure_errors
from tpods.demo.procs import lag_text
from tpods.demo.structure_layout import MODULES, POSITION_SIGMA_M, TRUSS_PARTS, outlines
from tpods.demo.timing import StageTimes, table_text, write_report_md

QUANTITIES = (("mass", "mass_kg", "mass_sigma_kg", "kg", 1.0, "{:.4f}"),
              ("izz", "izz_kgm2", "izz_sigma_kgm2", "kg m^2", 1.0, "{:.5g}"),
              ("cx", "com_x_m", "com_x_sigma_m", "mm", 1e3, "{:.2f}"),
              ("cy", "com_y_m", "com_y_sigma_m", "mm", 1e3, "{:.2f}"))
"""(short name, value key, sigma key, display unit, display factor, format)."""


def _gt_row(gt: dict[str, Any]) -> dict[str, Any]:
    return {"mass_kg": gt["mass_kg"], "mass_sigma_kg": gt["mass_sigma_kg"],
            "izz_kgm2": gt["izz_com_kgm2"], "izz_sigma_kgm2": gt["izz_com_sigma_kgm2"],
            "com_x_m": gt["com_m"][0], "com_x_sigma_m": gt["com_sigma_m"][0],
            "com_y_m": gt["com_m"][1], "com_y_sigma_m": gt["com_sigma_m"][1]}


def summary_rows(parts: dict[str, Any], live: dict[str, Any] | None, batch: dict[str, Any]
                 ) -> list[dict[str, Any]]:
    """One row per source: value, 1 sigma, error against the simulation's truth and the
    error in sigmas (None where the sigma is 0 or the result did not converge)."""
    truth = parts["truth"]
    rows = [{"source": "truth (simulation)", **truth, "mass_sigma_kg": 0.0, "izz_sigma_kgm2": 0.0,
             "com_x_sigma_m": 0.0, "com_y_sigma_m": 0.0},
            {"source": "parts (calibrate combine)", **_gt_row(parts["ground_truth"])}]
    if live is not None:
        ok = not live.get("diverged", False)
        rows.append({"source": f"live {live.get('method', 'ls-ekf')}" + ("" if ok else " DIVERGED"),
                     "converged": ok, **{k: live[k] for _, v, s, *_ in QUANTITIES for k in (v, s)}})
    rows.append({"source": "batch LS (recorded run)" + ("" if batch["converged"] else " NOT converged"),
                 "converged": bool(batch["converged"]),
                 **{k: batch[k] for _, v, s, *_ in QUANTITIES for k in (v, s)}})
    for r in rows:
        r.setdefault("converged", True)
        for _, v, s, *_ in QUANTITIES:
            err = float(r[v]) - float(truth[v])
            r[_err_key(v).replace("_sigmas", "_" + v.split("_")[-1])] = err
            sig = float(r[s])
            r[_err_key(v)] = err / sig if sig > 0 and r["converged"] else None
    return rows


def _err_key(value_key: str) -> str:
    return {"mass_kg": "mass_error_sigmas", "izz_kgm2": "izz_error_sigmas",
            "com_x_m": "com_x_error_sigmas", "com_y_m": "com_y_error_sigmas"}[value_key]


def table_lines(rows: list[dict[str, Any]], markdown: bool = False) -> list[str]:
    """The summary as text (or markdown) lines: for m, Izz (about the centre of mass), cx and
    cy the value, 1 sigma and the error in sigmas."""
    hdr = ["source"]
    for name, _, _, unit, _, _ in QUANTITIES:
        label = {"mass": "m", "izz": "Izz", "cx": "cx", "cy": "cy"}[name]
        hdr += [f"{label} [{unit}]", "sigma", "(err/sigma)"]
    body = []
    for r in rows:
        cells = [r["source"]]
        for _, v, s, _, f, fmt in QUANTITIES:
            z = r[_err_key(v)]
            cells += [fmt.format(r[v] * f), "0" if r[s] == 0 else f"{r[s] * f:.2g}",
                      "-" if z is None else f"{z:+.1f}"]
        body.append(cells)
    return table_text(hdr, body, markdown)


def _diag(sx: float, sy: float) -> list[list[float]]:
    return [[sx * sx, 0.0], [0.0, sy * sy]]


def plot_structure_figure(out: Path, parts: dict[str, Any], live: dict[str, Any] | None,
                          batch: dict[str, Any], level: float = 0.95) -> Path:
    """``structure.png``: the truss, its modules, the tracked frame, the true, parts, live
    and batch centres of mass with their ``level`` ellipses."""
    t = parts["truth"]
    gt = parts["ground_truth"]
    pts = [ComPoint("truth (simulation)", (t["com_x_m"], t["com_y_m"]), None, "k", "*"),
           ComPoint("parts (calibrate combine)", tuple(gt["com_m"]), _diag(*gt["com_sigma_m"]),
                    "C2", "D")]
    if live is not None:
        cov = live.get("cov_com_m2") or _diag(live["com_x_sigma_m"], live["com_y_sigma_m"])
        pts.append(ComPoint(f"live {live.get('method', 'ls-ekf')}", (live["com_x_m"], live["com_y_m"]),
                            cov, "C1", "s"))
    pts.append(ComPoint("batch LS", (batch["com_x_m"], batch["com_y_m"]), batch["cov_com_m2"],
                        "C0", "o"))
    return plot_structure(out / "structure.png", [(n, p[0], p[1], y) for n, p, y in MODULES], pts,
                          outlines=outlines(), level=level,
                          title="tpods demo --structure: two modules on a truss, centre of mass "
                                f"with {100 * level:g} % ellipses")


def plot_live_errors(out: Path, parts: dict[str, Any], live: dict[str, Any]) -> list[Path]:
    """``run/live_errors.png``: the live estimates' errors of m, Izz, cx, cy against time with
    their 3-sigma bands (from the recorded estimates.csv; nothing when it lacks a column)."""
    import pandas as pd  # lazy: only the report needs pandas here

    path = Path(live["run_dir"]) / "estimates.csv"
    cols = [v for _, v, _, *_ in QUANTITIES]
    sigs = [s for _, _, s, *_ in QUANTITIES]
    if not path.is_file():
        return []
    est = pd.read_csv(path)
    if not set(cols + sigs) <= set(est.columns) or len(est) < 2:
        return []
    t = parts["truth"]
    return [plot_structure_errors(est["t"].to_numpy(), est[cols].to_numpy(), est[sigs].to_numpy(),
                                  [t[c] for c in cols], out / "run" / "live_errors.png",
                                  title=f"Live {live.get('method')} on the structure: error and "
                                        "3 sigma")]


def _fig_lines(out: Path, figs: list[Path], folder: str | None) -> list[str]:
    rel = [Path(f).relative_to(out) for f in figs]
    return [f"![{p.stem}]({p.as_posix()})" for p in rel
            if (p.parts[0] == folder if folder else len(p.parts) == 1)]


def _compare_lines(label: str, rows: list[dict[str, Any]] | None) -> list[str]:
    if not rows:
        return []
    out = [f"`tpods calibrate combine parts.toml --compare` with the {label}:", "",
           "| quantity | parts | sigma | estimate | sigma | difference (combined sigmas) |",
           "|---|---|---|---|---|---|"]
    for r in rows:
        z = r.get("difference_sigmas")
        out.append(f"| {r['quantity']} [{r['unit']}] | {r['ground_truth']:.6g} | "
                   f"{r['ground_truth_sigma']:.2g} | {r['estimate']:.6g} | {r['estimate_sigma']:.2g} | "
                   f"{'-' if z is None else f'{z:+.1f}'} |")
    return out + [""]


def write_report(out: Path, args, rows, parts, run, live, batch, figs, times: StageTimes) -> Path:
    """``report.md`` of the structure variant (``live`` None: run with ``--no-live``)."""
    gt = parts["ground_truth"]
    t = parts["truth"]
    part_rows = ["| part | mass [kg] | sigma | Izz own [kg m^2] | position [m] |", "|---|---|---|---|---|"]
    for p in gt["parts"]:
        meas = next(q for q in parts["parts"] if q["name"] == p["name"])
        part_rows.append(f"| {p['name']} | {p['mass_kg']:.5f} | {meas['mass_sigma_kg']:.2g} | "
                         f"{p['izz_own_kgm2']:.4g} | ({p['position_m'][0]:.4f}, "
                         f"{p['position_m'][1]:.4f}) |")
    c = (live or {}).get("counters", {}) or {}
    live_lines = [f"No live estimator (`--no-live`): the demo recorded the poses itself and "
                  f"joined them with the player's commands in `{batch['run_dir']}`.", ""] \
        if live is None else [
        f"`tpods estimate live --structure structure/structure.toml --body truss --method "
        f"{args.method}` estimated from the Zenoh streams (the structure's poses and both modules' "
        f"commands) and recorded the run in `run/live/`"
        + (f": {c.get('poses_rx')} poses received, {c.get('align_poses_out', '-')} aligned with "
           f"their commands ({c.get('updates')} filter updates after the LS start, "
           f"{c.get('catchup_updates', 0)} on its catch-up); {c.get('cmds_rx')} command messages "
           f"from the {len(MODULES)} modules" + (f", merged into {c['merge_emitted']} rows"
                                                 if "merge_emitted" in c else "")
           if c else "") + ".", ""]
    lines = [
        "# TPODS lab day: a rigid structure moved by two modules (emulated)",
        "",
        f"Generated by `tpods demo --structure` on {_dt.datetime.now().isoformat(timespec='seconds')} "
        f"(seed {args.seed}). No hardware: the valve controllers and the balance are emulators "
        "behind pseudo-terminals, every network hop is Zenoh on loopback.",
        "",
        "## Summary",
        "",
        *table_lines(rows, markdown=True),
        "",
        f"Truth: the simulated structure, m = {t['mass_kg']:.5f} kg, Izz = {t['izz_kgm2']:.6g} kg m^2 "
        f"about its centre of mass at ({1e3 * t['com_x_m']:.3f}, {1e3 * t['com_y_m']:.3f}) mm in the "
        "tracked frame (the true parts combined). Izz is about the centre of mass; cx, cy are in the "
        "tracked frame. The modules' thrust is Table 2 in the plant and in the estimators (no "
        "calibration error here: the plain `tpods demo` shows that part), so every sigma is the "
        "measurement noise's; the parts' sigma is the balance's, the bifilar fit's and the tape's "
        f"({1e3 * POSITION_SIGMA_M:g} mm per axis). The estimators know only the modules' layout "
        "(`structure/structure.toml`): they start from two paper modules and no truss.",
        "",
        "## 1. The structure and its parts",
        "",
        "Modules: " + "; ".join(f"{n} at ({p[0]:g}, {p[1]:g}) m, yaw {y:g} deg" for n, p, y in MODULES)
        + ". Truss parts: " + "; ".join(f"{p['name']} {p['mass_kg']:g} kg ({p['shape']}) at "
                                        f"({p['position_m'][0]:g}, {p['position_m'][1]:g}) m"
                                        for p in TRUSS_PARTS)
        + " (true values). Every part was weighed on an emulated OHAUS Scout; each module's Izz "
        "comes from an emulated bifilar swing (D = 0.10 m, h = 1.0 m, 20 deg release, its trace "
        "fit); the truss parts' Izz from their shapes; the positions were taped. "
        "`tpods calibrate combine structure/parts.toml` (parallel-axis theorem) gives m = "
        f"{gt['mass_kg']:.5f} +- {gt['mass_sigma_kg']:.2g} kg, Izz = {gt['izz_com_kgm2']:.6g} +- "
        f"{gt['izz_com_sigma_kgm2']:.2g} kg m^2 about the centre of mass at "
        f"({1e3 * gt['com_m'][0]:.2f} +- {1e3 * gt['com_sigma_m'][0]:.2f}, {1e3 * gt['com_m'][1]:.2f} "
        f"+- {1e3 * gt['com_sigma_m'][1]:.2f}) mm.",
        "",
        *part_rows,
        "",
        *_fig_lines(out, figs, "structure"),
        "",
        "## 2. The structure run" + (", estimated live" if live is not None else ""),
        "",
        f"`tpods run plant --structure structure/truth.toml` served one emulated valve controller "
        f"per module and streamed 120 Hz poses of the tracked frame (1 cm, 1 deg noise) through the "
        f"bridge; `tpods run play --structure` played the phase-shifted sine on all "
        f"{4 * len(MODULES)} channels for {args.duration:g} s of lab time at time scale "
        f"{args.time_scale:g} (every module's valves closed at the end: "
        f"{(run.get('play') or {}).get('valves_closed_confirmed')}). "
        + lag_text(run.get("switch_lag_ms")),
        "",
        *live_lines,
        *_fig_lines(out, figs, "run"),
        "",
        "## 3. Batch least squares on the recorded run",
        "",
        f"Batch least squares on `{batch['run_dir']}` (`estimator.estimate.estimate_run`, what "
        f"`tpods estimate batch {batch['run_dir']}` runs) estimates {', '.join(batch['estimated'])}, "
        f"{batch.get('start') or 'from the structure file'}: "
        f"{'converged' if batch['converged'] else 'NOT converged'}; the 2x2 covariance of cx, cy "
        "for the figure comes from its fit.",
        "",
        *_compare_lines("batch estimate (batch/estimate.json)", batch.get("compare")),
        *_compare_lines("live estimate (run/live_summary.json)", (live or {}).get("compare")),
        "## Centre of mass",
        "",
        "The figure shows the structure in its tracked frame (origin O, axes xs, ys), each module "
        "with its four thrusters (red: the exhaust; the force points the other way), and the "
        "centres of mass: the truth, the parts' ground truth, the live and the batch estimates, "
        "each estimate with its 95 % ellipse (semi-axes sqrt(5.991 x eigenvalue) of its 2x2 "
        "covariance of cx, cy; the parts' covariance is diagonal, the combination propagating "
        "each axis alone). The ellipses are millimetres across: the right panel zooms on them.",
        "",
        *_fig_lines(out, figs, None),
        "",
        *_fig_lines(out, figs, "batch"),
        "",
    ]
    return write_report_md(out, lines, times)


def write_summary(out: Path, args, rows, parts, run, live, batch, timings) -> Path:
    """``summary.json``: the rows, the truth, the parts' ground truth, the live summary, the
    batch result with its centre-of-mass covariance, the timings."""
    def clean(d):
        return {k: v for k, v in (d or {}).items() if k != "figures"} if d is not None else None

    path = out / "summary.json"
    path.write_text(json.dumps(
        {"variant": "structure", "rows": rows, "truth": parts["truth"],
         "ground_truth": parts["ground_truth"], "live": clean(live), "batch": clean(batch),
         "play": run.get("play"), "plant": run.get("plant_log"),
         "switch_lag_ms": run.get("switch_lag_ms"), "run_timing_s": run.get("timing_s"),
         "time_scale": args.time_scale, "duration_lab_s": args.duration, "timings_s": timings},
        indent=2, default=str) + "\n")
    return path

