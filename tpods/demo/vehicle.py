"""``tpods demo --vehicle F``: the module-run stage of the lab day on a vehicle,
on emulated devices.

1. **run** (:func:`stage_vehicle_run`): ``tpods run plant --vehicle`` (one emulated
   N-channel valve driver on a pty, the vehicle's thrusters with its valve dead time and
   rise, the truth ``--mass``/``--izz``, 1 cm / 1 deg poses through the bridge over Zenoh),
   ``tpods estimate live --vehicle`` (ls-ekf: mass, Izz, centre of mass) and ``tpods run
   play --vehicle --input pulses`` (each valve fully open in turn: on/off valves) as
   subprocesses on a shared lab clock (``--time-scale``), over a private Zenoh network.
2. **batch**: batch least squares on the run the live estimator recorded
   (``tpods estimate batch`` of the folder, its vehicle.toml inside), with its residuals.

The summary table (truth, live, batch with the errors in sigmas), ``report.md`` and
``summary.json`` close it. The calibration stages of ``tpods demo`` (thrust bench, scale,
bifilar) are a TPODS module's and are not run for a vehicle.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import time
from pathlib import Path
from typing import Any

from common.errors import UserError
from common.vehicle import Vehicle
from common.wire import cmd_key
from tpods.demo import procs as dp
from tpods.demo.timing import StageTimes, print_summary, table_text, write_report_md

LIVE_WINDOW_FRACTION = 0.4
"""The live LS window: this fraction of the run (at most the estimator's 20 s default)."""


def _read_valves(proc: subprocess.Popen, timeout_s: float, log: Path) -> str:
    """The ``valves: PATH`` line ``tpods run plant --vehicle`` prints first."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        line = proc.stdout.readline()
        if line.startswith("valves: "):
            return line.split(": ", 1)[1].strip()
        if not line and proc.poll() is not None:
            break
    raise UserError(f"the simulated plant did not start (see {log})")


def stage_vehicle_run(out: Path, args: argparse.Namespace, vehicle: Vehicle,
                      vpath: Path) -> dict[str, Any]:
    """Plant, live estimator and player as subprocesses into ``out/run``; the live summary
    with the player's status, the valve-switch lag and the phases' wall time."""
    t_stage = time.monotonic()
    phases: dict[str, float] = {}
    d = out / "run"
    d.mkdir(parents=True, exist_ok=True)
    session, ep = dp.demo_session(args)
    zargs = dp.child_zenoh_args(args, ep)
    exe = dp.tpods_exe()
    clock = ["--time-scale", f"{args.time_scale:g}", "--clock-origin", repr(time.time())]
    window = min(20.0, LIVE_WINDOW_FRACTION * args.duration)
    procs: dict[str, subprocess.Popen] = {}
    logs: dict[str, Any] = {}
    try:
        logs["plant"] = (d / "plant.log").open("w")
        procs["plant"] = subprocess.Popen(
            exe + ["run", "plant", "--vehicle", str(vpath), "--mass", f"{args.mass!r}", "--izz",
                   f"{args.izz!r}", "--seed", str(args.seed), "--truth-out", str(d / "plant"),
                   *clock, *zargs], stdout=subprocess.PIPE, stderr=logs["plant"], text=True)
        valves = _read_valves(procs["plant"], 60.0, d / "plant.log")
        logs["live"] = (d / "live.log").open("w")
        procs["live"] = subprocess.Popen(
            exe + ["estimate", "live", "--vehicle", str(vpath), "--ls-window", f"{window:g}",
                   "--out", str(d / "live"), "--exit-on-end", "--max-wait-ms", "10", "--json",
                   "--quiet", *zargs], stdout=subprocess.PIPE, stderr=logs["live"], text=True)
        dp.wait_subscribed(session, cmd_key(vehicle.name), procs["live"], "the live estimator",
                           d / "live.log")
        time.sleep(0.3)
        print(f"   plant: {vehicle.n_channels} valves on {valves}; truth m {args.mass:g} kg, "
              f"Izz {args.izz:g} kg m^2, poses of {vehicle.name} at 120 Hz (1 cm, 1 deg)")
        print(f"   live estimator (ls-ekf, LS window {window:g} s) and player (pulses on "
              f"{vehicle.n_channels} channels) running; "
              f"{dp.lab_time_text(args.duration, args.time_scale)}")
        logs["play"] = (d / "play.log").open("w")
        procs["play"] = subprocess.Popen(
            exe + ["run", "play", "--vehicle", str(vpath), "--valves", valves, "--input",
                   "pulses", "--duration", f"{args.duration:g}", "--out", str(d / "play"),
                   "--no-progress", *clock, *zargs],
            stdout=logs["play"], stderr=subprocess.STDOUT, text=True)
        phases["start-up"] = time.monotonic() - t_stage
        phases["played"] = dp.finish_play(procs, d, args.duration, args.time_scale,
                                          "vehicle run (lab time)", "the valves")
        t_end = time.monotonic()
        summary = dp.live_summary(procs["live"], d / "live.log")
        phases["estimator's end"] = time.monotonic() - t_end
        (d / "live_summary.json").write_text(json.dumps(summary, indent=2) + "\n")
        dp.stop(procs["plant"], signal.SIGTERM)  # it writes its truth on the way out
        if procs["plant"].returncode != 0:
            raise UserError(f"the simulated plant failed (see {d / 'plant.log'})")
        summary.update(dp.run_outcome(d))
        summary["timing_s"] = phases
        dp.print_run_timing("vehicle run", summary["switch_lag_ms"], phases, args.time_scale)
        return summary
    finally:
        dp.stop_run(procs, logs, session)


def stage_vehicle_batch(out: Path, run_dir: Path) -> dict[str, Any]:
    """``tpods estimate batch`` (LS; the vehicle's scan start) on the recorded run, its
    estimate.json and residual figure in ``out/batch``."""
    from estimator.estimate import estimate_run
    from estimator.reports.plots.batch import plot_residuals

    d = out / "batch"
    d.mkdir(parents=True, exist_ok=True)
    est = estimate_run(run_dir, method="ls", estimate=None, clamp=True)
    data = est.to_dict()
    (d / "estimate.json").write_text(json.dumps(data, indent=2, default=str) + "\n")
    fig = plot_residuals(est.batch.t, est.batch.residuals, d / "batch_residuals.png",
                         title="Batch LS on the recorded vehicle run: residuals")
    print(f"   batch LS ({'converged' if est.batch.converged else 'NOT converged'}): m = "
          f"{data['mass_kg']:.4f} +- {data['mass_sigma_kg']:.2g} kg, Izz = "
          f"{data['izz_kgm2']:.5g} +- {data['izz_sigma_kgm2']:.2g} kg m^2")
    return {**{k: data.get(k) for k in _KEYS}, "converged": bool(est.batch.converged),
            "start": data.get("start"), "figure": fig}


_KEYS = ("mass_kg", "mass_sigma_kg", "izz_kgm2", "izz_sigma_kgm2", "com_x_m", "com_x_sigma_m",
         "com_y_m", "com_y_sigma_m")


def summary_rows(truth: dict[str, float], live: dict[str, Any],
                 batch: dict[str, Any]) -> list[dict[str, Any]]:
    """The summary table's rows: the truth, the live and the batch estimates with their
    errors in sigmas (mass, Izz)."""
    rows = [{"source": "truth (simulation)", **truth}]
    for name, e in (("live ls-ekf", live), ("batch LS (recorded run)", batch)):
        row = {"source": name, **{k: e.get(k) for k in _KEYS}}
        for q, s in (("mass_kg", "mass_sigma_kg"), ("izz_kgm2", "izz_sigma_kgm2")):
            row[f"{q}_error_sigmas"] = (e[q] - truth[q]) / e[s] if e.get(s) else None
        rows.append(row)
    return rows


def table_lines(rows: list[dict[str, Any]], markdown: bool = False) -> list[str]:
    hdr = ["source", "mass [kg]", "sigma", "err/sigma", "Izz [kg m^2]", "sigma", "err/sigma"]

    def f(v, fmt):
        return "-" if v is None else format(v, fmt)

    body = [[r["source"], f(r["mass_kg"], ".4f"), f(r.get("mass_sigma_kg"), ".2g"),
             f(r.get("mass_kg_error_sigmas"), "+.2f"), f(r["izz_kgm2"], ".5g"),
             f(r.get("izz_sigma_kgm2"), ".2g"), f(r.get("izz_kgm2_error_sigmas"), "+.2f")]
            for r in rows]
    return table_text(hdr, body, markdown)


def run_vehicle_demo(args: argparse.Namespace, out: Path, meta: dict | None = None) -> int:
    """The stages of ``tpods demo --vehicle F`` into ``out``, the summary and the report."""
    os.environ.setdefault("MPLBACKEND", "Agg")
    vpath = Path(args.vehicle).resolve()
    vehicle = Vehicle.load(vpath)
    truth = {"mass_kg": float(args.mass), "izz_kgm2": float(args.izz)}
    times = StageTimes(meta)
    print(f"TPODS lab day, a vehicle: {vehicle.name} ({vehicle.parts_text()}) on emulated "
          f"devices -> {out}")
    with times.stage("1/2 the vehicle run over Zenoh: run plant --vehicle, estimate live "
                     "--vehicle, run play --vehicle", "vehicle run"):
        live = stage_vehicle_run(out, args, vehicle, vpath)
        print(f"   live ls-ekf ({live.get('phase')}): m = {live['mass_kg']:.4f} +- "
              f"{live['mass_sigma_kg']:.2g} kg, Izz = {live['izz_kgm2']:.5g} +- "
              f"{live['izz_sigma_kgm2']:.2g} kg m^2")
    times.paced("vehicle run", args.duration / args.time_scale)
    with times.stage("2/2 batch least squares on the recorded run", "batch"):
        batch = stage_vehicle_batch(out, out / "run" / "live")
    rows = summary_rows(truth, live, batch)
    timings = times.timings()
    if meta is not None:
        meta["timings_s"] = timings
    fig = Path(batch.pop("figure")).relative_to(out)
    report = write_report_md(out, [
        f"# TPODS lab day on a vehicle: {vehicle.name}", "",
        f"{vehicle.parts_text()} (`{vpath.name}`); truth m = {args.mass:g} kg, Izz = "
        f"{args.izz:g} kg m^2; {dp.lab_time_text(args.duration, args.time_scale)}; seed "
        f"{args.seed}. Thrusters:", "", *(f"- {line}" for line in vehicle.describe()), "",
        "## Estimates", "", *table_lines(rows, markdown=True), "",
        dp.lag_text(live.get("switch_lag_ms")), "", f"![batch residuals]({fig})", ""], times)
    (out / "summary.json").write_text(json.dumps(
        {"vehicle": vehicle.name, "truth": truth, "rows": rows, "live": live, "batch": batch,
         "timings_s": timings, "duration_s": args.duration, "time_scale": args.time_scale,
         "seed": args.seed}, indent=2, default=str) + "\n")
    print_summary("summary (truth: the simulated vehicle; sigma 1 sigma; error in sigmas)",
                  table_lines(rows), times, f"vehicle run: {args.duration:g} s of lab time at "
                  f"time scale {args.time_scale:g}", report, 1)
    return 0
