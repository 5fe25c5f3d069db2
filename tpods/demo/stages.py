"""The flight and batch stages of ``tpods demo`` (see :mod:`tpods.demo.lab_day`; the bench stages
before them are in :mod:`tpods.demo.bench`): each runs one part of the lab day on emulated
devices, writes into its sub-folder of the report folder, prints a few lines and returns
what the summary and the report need.

- :func:`stage_run`: the simulated module, ``tpods estimate live`` and ``tpods run play`` as
  subprocesses over Zenoh on a shared lab clock -> ``run/``;
- :func:`stage_calibrate`: the calibration flight and ``calibrate thrust`` on it;
- :func:`stage_batch`: batch least squares on the recorded run -> ``batch/``.
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from common.gcpause import frozen_heap
from common.runfolder import read_run
from common.thrust_table import ThrustTable
from common.wire import cmd_key
from estimator.plant.model import PlantParams
from estimator.reports.plots.batch import plot_residuals
from tpods.clock import LabClock
from tpods.demo.fidelity import duty_time_error
from tpods.demo.fit import (
    BackgroundFit,
    batch_row,
    health_json,
    save_switches,
    segment_lines,
    segments_row_json,
    switch_row_json,
    switch_run,
)
from tpods.demo.procs import (
    child_failed,
    child_zenoh_args,
    demo_session,
    follow_player,
    lab_time_text,
    live_summary,
    print_run_timing,
    switch_lag_ms,
    tpods_exe,
    wait_recorded,
    wait_subscribed,
)
from tpods.demo.side import SideWork, residual_figure
from tpods.plant_loop import MocapNoise, SimulatedModule

# re-exported under their old names (tests/support, older callers)
_child_zenoh_args, _tpods_exe = child_zenoh_args, tpods_exe

BODY = "tpods1"

WEAK_THRUSTER = 3
WEAK_EFFICIENCY = 0.96
"""The module's nozzle 3 gives 4 % less thrust than the bench's nozzle (a pinched tube): the
bench characterises one nozzle and cannot see it; the calibration stage does."""


def plant_table() -> ThrustTable:
    """The simulated module's TRUE thrust: Table 2 with one weak thruster."""
    eff = [1.0] * 4
    eff[WEAK_THRUSTER - 1] = WEAK_EFFICIENCY
    d = ThrustTable.default().to_dict()
    d["calibration"] = {"efficiency": eff, "source": "tpods demo: the module's true thrusters"}
    return ThrustTable.from_dict(d)


def stage_run(out: Path, args: argparse.Namespace, table_path: Path, *, name: str = "run",
              input_name: str = "phase-sine", duration: float | None = None,
              on_recorded: Callable[[Path], None] | None = None) -> dict[str, Any]:
    """Simulated module (one weak thruster: :func:`plant_table`) + live estimator + player
    over Zenoh, into ``out/name``; returns the live summary, with the run's valve-switch lag
    (``switch_lag_ms``) and the wall time of its phases (``timing_s``).

    ``on_recorded(out/name)`` runs once the recording is whole (the estimator has sealed
    ``live/``'s poses and commands: :func:`tpods.demo.procs.wait_recorded`; ``truth.csv``
    and ``switches.csv`` written), beside the estimator's final fit."""
    duration = args.duration if duration is None else duration
    t_stage = time.monotonic()
    phases: dict[str, float] = {}
    d = out / name
    d.mkdir(parents=True, exist_ok=True)
    session, ep = demo_session(args)
    zargs = child_zenoh_args(args, ep)
    exe = tpods_exe()
    clock = LabClock(args.time_scale, time.time())
    params = PlantParams(args.mass, args.izz)
    procs: dict[str, subprocess.Popen] = {}
    logs = {}
    try:
        module = SimulatedModule(session, params, plant_table(), clock=clock, body=BODY,
                                 noise=MocapNoise(0.01, math.radians(1.0)), seed=args.seed)
        with frozen_heap(), module:  # the plant runs in this process: no long GC pause
            logs["live"] = (d / "live.log").open("w")
            procs["live"] = subprocess.Popen(
                exe + ["estimate", "live", "--body", BODY, "--thrust-table", str(table_path),
                       "--method", args.method, "--out", str(d / "live"), "--exit-on-end",
                       "--max-wait-ms", "10",
                       "--json", "--quiet", *zargs],
                stdout=subprocess.PIPE, stderr=logs["live"], text=True)
            # the player starts at the same time and waits for the estimator's subscription
            # (run play --wait-subscriber): their start-ups overlap
            logs["play"] = (d / "play.log").open("w")
            procs["play"] = subprocess.Popen(
                exe + ["run", "play", "--valves", module.valves_path, "--input", input_name,
                       "--duration", f"{duration:g}", "--body", BODY, "--out", str(d / "play"),
                       "--time-scale", f"{args.time_scale:g}", "--clock-origin", repr(clock.origin),
                       "--wait-subscriber", "60", "--no-progress", *zargs],
                stdout=logs["play"], stderr=subprocess.STDOUT, text=True)
            wait_subscribed(session, cmd_key(BODY), procs["live"], "the live estimator",
                            d / "live.log")
            print(f"   module: emulated valves on {module.valves_path}, truth m = {args.mass:g} kg, "
                  f"Izz = {args.izz:g} kg m^2, thrust truth Table 2 with thruster {WEAK_THRUSTER} "
                  f"at {WEAK_EFFICIENCY:.0%}, poses 120 Hz (1 cm, 1 deg)")
            print(f"   live estimator ({args.method}, {table_path.name}) and player ({input_name}) "
                  f"running; {lab_time_text(duration, args.time_scale)}")
            phases["start-up"] = time.monotonic() - t_stage
            phases["played"] = follow_player(procs["play"], duration, args.time_scale,
                                             f"{name} (lab time)")
            if procs["play"].returncode != 0:
                raise child_failed("player", procs["play"], d / "play.log")
            t_end = time.monotonic()
            # the estimator ends its stream (the end rule) and seals its data files before
            # its final fit; the plant stops once it has: every pose it uses is in
            sealed = wait_recorded(d / "live", procs["live"])
            phases["until recorded"] = time.monotonic() - t_end
        summary = None if sealed else live_summary(procs["live"], d / "live.log")
        t_truth, s_truth = module.plant.truth_arrays()
        t0_lab = json.loads((d / "live" / "run.json").read_text()).get("t0_lab") or t_truth[0]
        np.savetxt(d / "truth.csv", np.column_stack([t_truth - t0_lab, s_truth]), delimiter=",",
                   header="t,x,y,psi,u,v,r", comments="", fmt="%.12g")
        save_switches(d / "switches.csv", module.plant.switches, t0_lab)
        if on_recorded is not None:
            t_beside = time.monotonic()
            on_recorded(d)
            phases["beside its final fit"] = time.monotonic() - t_beside
        if summary is None:
            summary = live_summary(procs["live"], d / "live.log")
        phases["estimator's end"] = time.monotonic() - t_end
        play_meta = json.loads((d / "play" / "run.json").read_text())
        summary["play"] = {k: play_meta.get(k) for k in ("status", "valves_closed_confirmed",
                                                         "counts", "timing")}
        summary["plant"] = {"poses": module.plant.frames, "max_behind_lab_s":
                            module.plant.max_behind_s, "valve_changes": len(module.plant.switches)}
        summary["switch_lag_ms"] = lag = switch_lag_ms(module.plant.switches, d / "play")
        summary["duty_time_error"] = duty_time_error(module.plant.switches, d / "play")
        summary["truth_t"], summary["truth_s"], summary["t0_lab"] = t_truth - t0_lab, s_truth, t0_lab
        summary["timing_s"], summary["duration_lab_s"] = phases, duration
        summary["time_scale"] = args.time_scale
        print_run_timing(name, lag, phases, args.time_scale)
        return summary
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
                try:
                    p.wait(10)
                except subprocess.TimeoutExpired:
                    p.kill()
        for fh in logs.values():
            fh.close()
        session.close()


def stage_calibrate(out: Path, args: argparse.Namespace, bench: dict[str, Any],
                    mass: dict[str, Any], bif: dict[str, Any]) -> dict[str, Any]:
    """The module as the known body: a translate-rotate run (every thruster opens alone with
    its partner, so each one's efficiency is seen), then ``tpods calibrate thrust`` with the
    balance's mass and the bifilar Izz -> ``calibration/thrust_table.toml``."""
    from estimator.batch.thrust_calibration.calibrate import calibrate_run

    duration = 28.0 if args.quick else 42.0  # two or three 14 s cycles
    # at the run's time scale: the factors' shared error once blamed on it was the bench
    # table's (a zero shared by three steps; see stage_bench). A late switch on a busy
    # machine is an impulse error the efficiencies would absorb: stage_run measures the
    # switches' lag and warns when the machine cannot keep up
    got: dict[str, Any] = {}

    def calibrate(d: Path) -> None:
        """``calibrate thrust`` on the sealed recording, beside the estimator's final fit."""
        res = calibrate_run(read_run(d / "live"), bench["table"], mass_kg=mass["mass_kg"],
                            mass_sigma_kg=mass["sigma_kg"], izz_kgm2=bif["izz_kgm2"],
                            izz_sigma_kgm2=bif["sigma_kgm2"], per="thruster", clamp=True)
        got["table"] = res.new_table(bench["table"], source="tpods demo: calibrate thrust",
                                     run=str(d / "live"))
        got["table"].save(d / "thrust_table.toml")
        (d / "calibration.json").write_text(json.dumps(res.to_dict(), indent=2, default=str)
                                            + "\n")
        got["res"] = res

    live = stage_run(out, args, bench["table_path"], name="calibration",
                     input_name="translate-rotate", duration=duration, on_recorded=calibrate)
    d = out / "calibration"
    res, table, path = got["res"], got["table"], d / "thrust_table.toml"
    sig = res.sigma
    truth = [1.0] * 4
    truth[WEAK_THRUSTER - 1] = WEAK_EFFICIENCY
    factors = []
    for j, name in enumerate(res.names):
        k = int(name.split(".")[1]) - 1
        factors.append({"name": name, "value": float(res.values[j]), "sigma": float(sig[j]),
                        "truth": truth[k]})
        print(f"   {name} = {res.values[j]:.4f} +- {sig[j]:.2g} (truth {truth[k]:.2f}: "
              f"{(res.values[j] - truth[k]) / sig[j]:+.1f} sigma)")
    print(f"   calibrated table: {path} (the bench coefficients, these factors and their covariance)")
    timing = live["duty_time_error"]
    print("   the emulated valves' open time against the commands: "
          + ", ".join(f"d{k + 1} {e:+.2f} %" for k, e in enumerate(timing["per_channel_pct"])))
    if timing["max_abs_pct"] > 100.0 * float(np.min(sig)):
        print(f"tpods: warning: the machine was too loaded for this flight: the emulated valves "
              f"were open {timing['max_abs_pct']:.2g} % longer or shorter than commanded on one "
              f"channel, more than the factors' sigma ({100.0 * float(np.min(sig)):.2g} %): the "
              "factors carry that timing error (tpods/demo/fidelity.py)", file=sys.stderr)
    return {"table_path": path, "table": table, "factors": factors, "live": live,
            "converged": res.converged}


def _json(d: dict[str, Any]) -> str:
    return json.dumps(d, indent=2, default=str) + "\n"


def side_fits(out: Path, bench_table, side: SideWork, beside: str = "beside"
              ) -> dict[str, Any]:
    """Two of :func:`stage_batch`'s fits submitted to the side workers (``beside`` names
    what they run beside): the bench-table fit (it does not converge: the longest) and the
    check fit with the plant's true table and valve switches; futures of their rows."""
    return {"before": side.submit(f"batch: bench-table fit by segments ({beside})",
                                  segments_row_json, out / "run" / "live", bench_table, False),
            "health": side.submit(f"batch: thruster health, bench table ({beside})",
                                  health_json, out / "run" / "live", bench_table),
            "check": side.submit(f"batch: true-table check fit ({beside})", switch_row_json,
                                 out / "run" / "live", out / "run" / "switches.csv",
                                 plant_table())}


def stage_batch(out: Path, bench_table, calibrated_table=None, side: SideWork | None = None,
                early: dict[str, Any] | None = None) -> dict[str, Any]:
    """Batch least squares on the run the live estimator recorded: with the bench table
    (before calibration), the calibrated table (after) and the plant's true table (check).

    With a calibrated table, the fit with the bench table (it does not converge: it runs
    out of iterations or steps, the longest of the three) runs in a process of its own
    while this one fits the other two and draws the residuals: the same fits, in parallel.
    With ``side`` (the demo's pre-warmed workers, :mod:`tpods.demo.side`), the bench-table
    fit and the check fit run there (no process to start) while this one fits the
    calibrated table and draws the residuals; ``early``: those two already submitted
    (:func:`side_fits`, once the module run's recording was sealed)."""
    d = out / "batch"
    d.mkdir(parents=True, exist_ok=True)
    run = read_run(out / "run" / "live")
    if side is not None and calibrated_table is not None:
        return _batch_beside(d, run, calibrated_table, early or side_fits(out, bench_table, side),
                             side)
    bg = BackgroundFit(out / "run" / "live", bench_table) if calibrated_table is not None else None
    try:
        after = batch_row(run, calibrated_table) if calibrated_table is not None else None
        # the same fit with the plant's true thrust table and its own valve switch times
        # (not the player's stamps, which the valves follow late): what is left is noise
        chk = batch_row(switch_run(run, out / "run" / "switches.csv"), plant_table())
        before = batch_row(run, bench_table) if bg is None else None
        res = (after or before)["res"]
        fig = plot_residuals(res.t, res.residuals, d / "batch_residuals.png",
                             title="Batch LS on the recorded run: residuals")
        if bg is not None:
            before = bg.result()
            (d / "estimate_before_calibration.json").write_text(_json(before.pop("res_dict")))
    finally:
        if bg is not None:
            bg.stop()
    return _batch_done(d, res, before, after, chk, fig)


def _batch_beside(d: Path, run, calibrated_table, fits: dict[str, Any], side: SideWork
                  ) -> dict[str, Any]:
    """:func:`stage_batch` into ``d`` with the bench-table fit and the check fit in side
    workers (``fits``: :func:`side_fits`)."""
    f_before, f_chk = fits["before"], fits["check"]
    after = batch_row(run, calibrated_table)
    res = after["res"]
    # drawn by the worker that is free first (the other still fits the bench table)
    f_fig = side.submit("batch: residual figure (beside)", residual_figure, res.t,
                        res.residuals, d / "batch_residuals.png",
                        "Batch LS on the recorded run: residuals")
    before = {**f_before.result(), "health": fits["health"].result()}
    before["res_dict"]["thruster_health"] = before["health"]["thrusters"]
    (d / "estimate_before_calibration.json").write_text(_json(before.pop("res_dict")))
    return _batch_done(d, res, before, after, f_chk.result(), f_fig.result())


def _batch_done(d: Path, res, before, after, chk, fig) -> dict[str, Any]:
    """The end of :func:`stage_batch`: estimate.json, the printed lines, the stage's result."""
    (d / "estimate.json").write_text(_json(res.to_dict()))
    for label, r in (("bench table (before calibration)", before), ("calibrated table", after)):
        if r is None:
            continue
        how = f", by segments ({r['segments']})" if r.get("method") == "segments" else ""
        print(f"   batch LS, {label}{how}: m = {r['mass_kg']:.5f} +- {r['mass_sigma_kg']:.2g} kg "
              f"(noise {r['mass_sigma_noise_kg']:.2g}, thrust {r['mass_sigma_thrust_kg']:.2g}), "
              f"Izz = {r['izz_kgm2']:.6g} +- {r['izz_sigma_kgm2']:.2g} kg m^2 "
              f"({'converged' if r['converged'] else 'NOT converged'}; fit {r['fit_s']:.1f} s)")
        for line in segment_lines(r):
            print(f"     {line}")
    print(f"   check with the TRUE thrust table: m = {chk['mass_kg']:.5f} +- "
          f"{chk['mass_sigma_kg']:.2g} kg, Izz = {chk['izz_kgm2']:.6g} +- "
          f"{chk['izz_sigma_kgm2']:.2g} kg m^2 (at the plant's own valve switch times; noise "
          f"only: the true table states no uncertainty; fit {chk['fit_s']:.1f} s)")
    strip = lambda r: None if r is None else {k: v for k, v in r.items() if k != "res"}  # noqa: E731
    return {**strip(after or before), "before": strip(before), "after": strip(after),
            "figures": [fig], "true_table": strip(chk)}
