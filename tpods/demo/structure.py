"""``tpods demo --structure``: the lab day of a rigid structure on emulated devices.

Two modules bolted to a truss that also carries a payload; the tracked frame is the
structure's (its origin is not the centre of mass). Stages, each into its folder of the
demo's report folder:

1. **parts** (:func:`stage_parts`): the lab's ``structure/structure.toml`` (modules only:
   the estimators start from its geometry and know nothing of the truss), every part weighed
   on an emulated OHAUS Scout, each module's Izz from an emulated bifilar swing, the truss
   parts' Izz from their shapes, their positions taped (2 mm); ``parts.toml`` and the ground
   truth by parts from ``tpods calibrate combine`` (parallel-axis theorem, with sigma).
   The simulation's truth is the same parts with their TRUE values (``truth.toml``: the
   structure with its true ``[body]``, read only by the simulated plant).
2. **run** (:func:`stage_structure_run`): ``tpods run plant --structure`` (one emulated valve
   controller per module on a pty, the exact plant, 1 cm / 1 deg poses of the tracked frame
   through the bridge over Zenoh), ``tpods estimate live --structure --method ls-ekf`` and
   ``tpods run play --structure`` (the phase-shifted sine over all eight channels) as
   subprocesses on a shared lab clock (``--time-scale``).
3. **batch** (:func:`stage_structure_batch`): batch least squares on the run the live
   estimator recorded (m, Izz about the centre of mass, cx, cy and their covariance), and
   ``tpods calibrate combine --compare`` of the live and batch estimates with the parts.

The structure itself (modules, truss parts, tape) is in :mod:`tpods.demo.structure_layout`;
the report (:mod:`tpods.demo.structure_report`) holds the summary table and the figure of
the structure with the true, parts, live and batch centres of mass and their 95 % ellipses.
"""

from __future__ import annotations

import argparse
import json
import os
import queue
import shutil
import signal
import subprocess
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from calibration.composite import Part, combine, part_izz
from calibration.plots import plot_trace_fit
from calibration.swing.bifilar import swing_and_estimate
from common.errors import UserError
from common.wire import cmd_key, decode_pose, pose_key
from estimator.estimate import estimate_run
from estimator.reports.plots.batch import plot_residuals
from tpods.demo import procs as dp
from tpods.demo.bench import stage_mass
from tpods.demo.structure_layout import (
    BODY,
    MODULES,
    POSITION_SIGMA_M,
    TRUSS_PARTS,
    module_toml,
    outlines,
    shape_keys,
)


def stage_parts(out: Path, args: argparse.Namespace) -> dict[str, Any]:
    """The structure file, the truth, the parts measured on emulated instruments and their
    combination by ``tpods calibrate combine`` (a subprocess, as the lab runs it)."""
    d = out / "structure"
    d.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(args.seed + 100)
    # the simulation's truth: every part's true mass, Izz and position
    true_parts = [Part(f"module {n}", args.mass, args.izz, *p) for n, p, _ in MODULES]
    true_parts += [Part(p["name"], p["mass_kg"], part_izz(dict(shape_keys(p)), p["mass_kg"], p["name"]),
                        *p["position_m"]) for p in TRUSS_PARTS]
    truth = combine(true_parts, "com")
    structure_path = d / "structure.toml"
    structure_path.write_text(tomli_w.dumps(module_toml()))
    truth_path = d / "truth.toml"
    truth_path.write_text("# the SIMULATION's truth (read by tpods run plant only; the estimators "
                          "never see it)\n" + tomli_w.dumps(module_toml(
                              {"mass_kg": truth.mass_kg, "izz_kgm2": truth.izz_com_kgm2,
                               "com_m": list(truth.com_m)})))
    print(f"   {structure_path}: modules {', '.join(f'{n} at ({p[0]:g}, {p[1]:g}) m yaw {y:g} deg' for n, p, y in MODULES)}; "
          f"truth (simulation): m = {truth.mass_kg:.4f} kg, Izz = {truth.izz_com_kgm2:.5g} kg m^2 about "
          f"the centre of mass ({1e3 * truth.com_m[0]:.2f}, {1e3 * truth.com_m[1]:.2f}) mm")
    # the lab's measurements: balance, bifilar, tape
    parts_toml: list[dict[str, Any]] = []
    figs = []
    for k, tp in enumerate(true_parts):
        print(f"   {tp.name}:", end="")
        mass = stage_mass(tp.mass_kg, args.seed + 10 + k)
        pos = [float(v + rng.normal(0.0, POSITION_SIGMA_M)) for v in (tp.x_m, tp.y_m)]
        row: dict[str, Any] = {"name": tp.name, "mass_kg": mass["mass_kg"],
                               "mass_sigma_kg": mass["sigma_kg"]}
        if k < len(MODULES):
            swing = swing_and_estimate(mass["mass_kg"], tp.izz_kgm2, spacing_m=0.10, length_m=1.0,
                                       release_deg=20.0, duration_s=30.0, seed=args.seed + 20 + k,
                                       u_mass_kg=mass["sigma_kg"], u_spacing_m=0.0005,
                                       u_length_m=0.002)
            row.update(izz_kgm2=swing.fit.izz_kgm2, izz_sigma_kgm2=swing.fit.izz_sigma_kgm2)
            figs.append(plot_trace_fit(swing.fit, d / f"bifilar_{MODULES[k][0]}.png"))
            print(f"     bifilar swing: Izz = {swing.fit.izz_kgm2:.6g} +- "
                  f"{swing.fit.izz_sigma_kgm2:.2g} kg m^2 (truth {tp.izz_kgm2:.6g})")
        else:
            row.update(shape_keys(TRUSS_PARTS[k - len(MODULES)]))
        row.update(position_m=pos, position_sigma_m=POSITION_SIGMA_M)
        parts_toml.append(row)
    parts_path = d / "parts.toml"
    parts_path.write_text(
        "# the structure's parts as measured (tpods demo --structure): masses on the emulated "
        "balance,\n# module Izz from emulated bifilar swings, truss parts' Izz from their shapes, "
        f"positions taped ({1e3 * POSITION_SIGMA_M:g} mm)\n"
        + tomli_w.dumps({"about": "com", "part": parts_toml}))
    r = subprocess.run(dp.tpods_exe() + ["calibrate", "combine", str(parts_path), "--json"],
                       capture_output=True, text=True, timeout=60)
    if r.returncode != 0:
        raise UserError(f"tpods calibrate combine {parts_path} failed: "
                        f"{(r.stderr.strip().splitlines() or ['no message'])[-1]}")
    gt = json.loads(r.stdout)
    (d / "ground_truth.json").write_text(json.dumps(gt, indent=2) + "\n")
    print(f"   tpods calibrate combine {parts_path.name}: m = {gt['mass_kg']:.4f} +- "
          f"{gt['mass_sigma_kg']:.2g} kg, Izz = {gt['izz_com_kgm2']:.5g} +- "
          f"{gt['izz_com_sigma_kgm2']:.2g} kg m^2, centre of mass ({1e3 * gt['com_m'][0]:.2f} +- "
          f"{1e3 * gt['com_sigma_m'][0]:.2f}, {1e3 * gt['com_m'][1]:.2f} +- "
          f"{1e3 * gt['com_sigma_m'][1]:.2f}) mm")
    return {"structure_path": structure_path, "truth_path": truth_path, "parts_path": parts_path,
            "truth": {"mass_kg": truth.mass_kg, "izz_kgm2": truth.izz_com_kgm2,
                      "com_x_m": truth.com_m[0], "com_y_m": truth.com_m[1]},
            "ground_truth": gt, "parts": parts_toml, "figures": figs}


def _read_valves(proc: subprocess.Popen, n: int, timeout_s: float, log: Path) -> dict[str, str]:
    """The ``valves NAME: PATH`` lines ``tpods run plant --structure`` prints first (read by a
    thread: a buffered pipe may hold both lines after one read)."""
    lines: queue.Queue[str] = queue.Queue()

    def pump() -> None:
        for line in proc.stdout:
            lines.put(line)

    threading.Thread(target=pump, name="plant-stdout", daemon=True).start()
    paths: dict[str, str] = {}
    deadline = time.monotonic() + timeout_s
    while len(paths) < n:
        left = deadline - time.monotonic()
        if left <= 0 or (proc.poll() is not None and lines.empty()):
            raise UserError(f"the simulated plant did not start (see {log})")
        try:
            line = lines.get(timeout=min(left, 0.5))
        except queue.Empty:
            continue
        if line.startswith("valves ") and ": " in line:
            name, path = line.strip().removeprefix("valves ").split(": ", 1)
            paths[name] = path
    return paths


class _PoseTap:
    """The demo's own recording of the structure's poses (``--no-live``: batch only)."""

    def __init__(self, session, key: str) -> None:
        self.rows: list[tuple[float, float, float, float]] = []
        self.sub = session.declare_subscriber(key, self._on)

    def _on(self, sample) -> None:
        d = decode_pose(sample.payload.to_bytes())
        if d is not None and not d["occluded"]:
            self.rows.append((d["t"], d["x"], d["y"], d["yaw"]))

    def write_run(self, play_dir: Path, dest: Path, structure_path: Path) -> Path:
        """A run folder from the player's commands and these poses (t from the first command)."""
        self.sub.undeclare()
        dest.mkdir(parents=True, exist_ok=True)
        meta = json.loads((play_dir / "run.json").read_text())
        t0 = float(meta["t0_lab"])
        cmd_t = np.loadtxt(play_dir / "commands.csv", delimiter=",", skiprows=1, ndmin=2)[:, 0]
        shutil.copy(play_dir / "commands.csv", dest / "commands.csv")
        shutil.copy(structure_path, dest / "structure.toml")
        p = np.array(sorted(self.rows), float).reshape(-1, 4)
        p[:, 0] -= t0
        p = p[(p[:, 0] >= cmd_t[0]) & (p[:, 0] <= cmd_t[-1])]  # inside the commanded span
        p[:, 3] = np.unwrap(p[:, 3])
        np.savetxt(dest / "poses.csv", p, delimiter=",", header="t,x,y,psi", comments="",
                   fmt="%.9f")
        (dest / "run.json").write_text(json.dumps(
            {"status": "complete", "source": "tpods demo --structure --no-live: the demo's own "
             "recording of the poses and the player's commands", "t0_lab": t0}, indent=2) + "\n")
        return dest


def stage_structure_run(out: Path, args: argparse.Namespace, parts: dict[str, Any]) -> dict[str, Any]:
    """``tpods run plant --structure``, ``tpods estimate live --structure`` and ``tpods run
    play --structure`` as subprocesses over a private Zenoh network on one lab clock, into
    ``out/run``; returns the live summary (or, with ``--no-live``, what the demo recorded)."""
    t_stage = time.monotonic()
    phases: dict[str, float] = {}
    d = out / "run"
    d.mkdir(parents=True, exist_ok=True)
    session, ep = dp.demo_session(args)
    zargs = dp.child_zenoh_args(args, ep)
    exe = dp.tpods_exe()
    spath, tpath = parts["structure_path"], parts["truth_path"]
    origin = time.time()
    clock = ["--time-scale", f"{args.time_scale:g}", "--clock-origin", repr(origin)]
    names = [n for n, _, _ in MODULES]
    procs: dict[str, subprocess.Popen] = {}
    logs: dict[str, Any] = {}
    tap = None
    try:
        logs["plant"] = (d / "plant.log").open("w")
        procs["plant"] = subprocess.Popen(
            exe + ["run", "plant", "--structure", str(tpath), "--body", BODY, "--seed",
                   str(args.seed), "--truth-out", str(d / "plant"), *clock, *zargs],
            stdout=subprocess.PIPE, stderr=logs["plant"], text=True)
        valves = _read_valves(procs["plant"], len(names), 60.0, d / "plant.log")
        if args.no_live:
            tap = _PoseTap(session, pose_key("tpods/mocap", BODY))
        else:
            logs["live"] = (d / "live.log").open("w")
            procs["live"] = subprocess.Popen(
                exe + ["estimate", "live", "--structure", str(spath), "--body", BODY,
                       "--method", args.method, "--out", str(d / "live"), "--exit-on-end",
                       "--max-wait-ms", "10", "--json", "--quiet", *zargs],
                stdout=subprocess.PIPE, stderr=logs["live"], text=True)
            for n in names:  # it listens to every module's commands
                dp.wait_subscribed(session, cmd_key(n), procs["live"], "the live estimator",
                                 d / "live.log")
            time.sleep(0.3)
        print(f"   plant: {', '.join(f'{n} valves on {valves[n]}' for n in names)}; truth from "
              f"{tpath.name}, poses of {BODY} at 120 Hz (1 cm, 1 deg)")
        print(f"   {'live estimator (' + args.method + ') and ' if not args.no_live else ''}player "
              f"(phase-sine on {4 * len(names)} channels) running; "
              f"{dp.lab_time_text(args.duration, args.time_scale)}")
        logs["play"] = (d / "play.log").open("w")
        procs["play"] = subprocess.Popen(
            exe + ["run", "play", "--structure", str(spath), "--valves",
                   ",".join(f"{n}={valves[n]}" for n in names), "--input", "phase-sine",
                   "--duration", f"{args.duration:g}", "--out", str(d / "play"), "--no-progress",
                   *clock, *zargs],
            stdout=logs["play"], stderr=subprocess.STDOUT, text=True)
        t_played = time.monotonic()
        phases["start-up"] = t_played - t_stage
        phases["played"] = dp.finish_play(procs, d, args.duration, args.time_scale,
                                          "structure run (lab time)", "every module's valves")
        summary: dict[str, Any] = {}
        if not args.no_live:
            t_end = time.monotonic()
            summary = dp.live_summary(procs["live"], d / "live.log")
            phases["estimator's end"] = time.monotonic() - t_end
            summary.setdefault("method", args.method)
            (d / "live_summary.json").write_text(json.dumps(summary, indent=2) + "\n")
            summary["run_dir"] = d / "live"
        else:
            summary["run_dir"] = tap.write_run(d / "play", d / "recorded", spath)
        dp.stop(procs["plant"], signal.SIGTERM)  # it writes its truth on the way out
        if procs["plant"].returncode != 0:
            raise UserError(f"the simulated plant failed (see {d / 'plant.log'})")
        outcome = dp.run_outcome(d, dp.STRUCTURE_LAG_WARN_MS)
        summary["play"] = outcome["play"]
        summary["plant_log"] = (d / "plant.log").read_text().strip().splitlines()[-1:]
        summary["switch_lag_ms"] = lag = outcome["switch_lag_ms"]
        summary["timing_s"] = phases
        dp.print_run_timing("structure run", lag, phases, args.time_scale)
        return summary
    finally:
        dp.stop_run(procs, logs, session)


def _cov2(names: tuple[str, ...], cov: np.ndarray, a: str = "cx", b: str = "cy") -> list[list[float]]:
    i, j = 6 + names.index(a), 6 + names.index(b)
    return [[float(cov[i, i]), float(cov[i, j])], [float(cov[j, i]), float(cov[j, j])]]


def _compare(parts_path: Path, est_path: Path) -> subprocess.Popen:
    """``tpods calibrate combine PARTS --compare EST --json``, started (see :func:`_compared`)."""
    return subprocess.Popen(dp.tpods_exe() + ["calibrate", "combine", str(parts_path), "--compare",
                                              str(est_path), "--json"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _compared(proc: subprocess.Popen, est_path: Path) -> list[dict[str, Any]]:
    """The comparison rows of a :func:`_compare` process."""
    try:
        stdout, stderr = proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        proc.kill()
        stdout, stderr = proc.communicate()
    if proc.returncode != 0:
        raise UserError(f"tpods calibrate combine --compare {est_path} failed: "
                        f"{(stderr.strip().splitlines() or ['no message'])[-1]}")
    return json.loads(stdout)["comparison"]


def stage_structure_batch(out: Path, run_dir: Path, parts: dict[str, Any],
                          live: dict[str, Any] | None) -> dict[str, Any]:
    """Batch LS (m, Izz, cx, cy) on the recorded run with the modules' tables (Table 2) and
    the structure's geometric start; the parts' comparison with the live and batch results."""
    d = out / "batch"
    d.mkdir(parents=True, exist_ok=True)
    live_path = out / "run" / "live_summary.json"
    # the live estimate's comparison runs while the batch fit does
    live_cmp = _compare(parts["parts_path"], live_path) if live is not None and live_path.is_file() \
        else None
    try:
        return _batch_and_compare(out, d, run_dir, parts, live, live_cmp, live_path)
    finally:
        if live_cmp is not None and live_cmp.poll() is None:
            live_cmp.kill()
            live_cmp.wait()


def _batch_and_compare(out: Path, d: Path, run_dir: Path, parts: dict[str, Any],
                       live: dict[str, Any] | None, live_cmp: subprocess.Popen | None,
                       live_path: Path) -> dict[str, Any]:
    est = estimate_run(run_dir, method="ls", estimate=None, clamp=True)  # `tpods estimate batch`
    res = est.batch
    data = est.to_dict()
    (d / "estimate.json").write_text(json.dumps(data, indent=2, default=str) + "\n")
    fig = plot_residuals(res.t, res.residuals, d / "batch_residuals.png",
                         title="Batch LS on the recorded structure run: residuals")
    out_d = {"mass_kg": data["mass_kg"], "mass_sigma_kg": data["mass_sigma_kg"],
             "izz_kgm2": data["izz_kgm2"], "izz_sigma_kgm2": data["izz_sigma_kgm2"],
             "com_x_m": data["com_x_m"], "com_x_sigma_m": data["com_x_sigma_m"],
             "com_y_m": data["com_y_m"], "com_y_sigma_m": data["com_y_sigma_m"],
             "cov_com_m2": _cov2(tuple(res.names), res.cov), "converged": bool(res.converged),
             "estimated": list(res.names), "start": data.get("start"),
             "run_dir": str(Path(run_dir).relative_to(out))}
    print(f"   batch LS ({'converged' if res.converged else 'NOT converged'}; {data.get('start')}): "
          f"m = {out_d['mass_kg']:.4f} +- {out_d['mass_sigma_kg']:.2g} kg, Izz = "
          f"{out_d['izz_kgm2']:.5g} +- {out_d['izz_sigma_kgm2']:.2g} kg m^2, centre of mass "
          f"({1e3 * out_d['com_x_m']:.2f} +- {1e3 * out_d['com_x_sigma_m']:.2f}, "
          f"{1e3 * out_d['com_y_m']:.2f} +- {1e3 * out_d['com_y_sigma_m']:.2f}) mm")
    out_d["compare"] = _compared(_compare(parts["parts_path"], d / "estimate.json"),
                                 d / "estimate.json")
    if live_cmp is not None:
        live["compare"] = _compared(live_cmp, live_path)
    return {**out_d, "figures": [fig]}


def run_structure_demo(args: argparse.Namespace, out: Path, meta: dict | None = None) -> int:
    """The stages of ``tpods demo --structure`` into ``out``, the summary and the report;
    each stage's wall time into ``meta`` (run.json's ``timings_s``) when given."""
    os.environ.setdefault("MPLBACKEND", "Agg")
    from tpods.demo.structure_report import (
        plot_live_errors,
        plot_structure_figure,
        summary_rows,
        table_lines,
        write_report,
        write_summary,
    )
    from tpods.demo.timing import StageTimes, print_summary

    times = StageTimes(meta)
    print(f"TPODS lab day, a structure: two modules on a truss, on emulated devices -> {out}")

    with times.stage("1/3 the structure and its parts: balance, bifilar, tape; tpods calibrate "
                     "combine", "parts + calibrate combine"):
        parts = stage_parts(out, args)

    with times.stage("2/3 the structure run over Zenoh: run plant --structure, "
                     + ("" if args.no_live else "estimate live --structure, ")
                     + "run play --structure", "structure run"):
        run = stage_structure_run(out, args, parts)
        live = None if args.no_live else run
        if live is not None:
            print(f"   live {live.get('method', args.method)} ({live.get('phase')}): m = "
                  f"{live['mass_kg']:.4f} +- {live['mass_sigma_kg']:.2g} kg, Izz = "
                  f"{live['izz_kgm2']:.5g} +- {live['izz_sigma_kgm2']:.2g} kg m^2, centre of mass "
                  f"({1e3 * live['com_x_m']:.2f} +- {1e3 * live['com_x_sigma_m']:.2f}, "
                  f"{1e3 * live['com_y_m']:.2f} +- {1e3 * live['com_y_sigma_m']:.2f}) mm")
    times.paced("structure run", args.duration / args.time_scale)

    with times.stage("3/3 batch least squares on the recorded run; the parts compared",
                     "batch + compare"):
        batch = stage_structure_batch(out, Path(run["run_dir"]), parts, live)

    with times.stage(None, "figures"):
        rows = summary_rows(parts, live, batch)
        figs = (parts["figures"] + [plot_structure_figure(out, parts, live, batch)]
                + (plot_live_errors(out, parts, live) if live is not None else [])
                + batch["figures"])
    timings = times.timings()
    if meta is not None:
        meta["timings_s"] = timings
    report = write_report(out, args, rows, parts, run, live, batch, figs, times)
    write_summary(out, args, rows, parts, run, live, batch, timings)
    print_summary("summary (truth: the simulated structure; sigma 1 sigma; error in sigmas)",
                  table_lines(rows), times, f"structure run: {args.duration:g} s of lab time at "
                  f"time scale {args.time_scale:g}", report, len(figs))
    return 0


__all__ = ["BODY", "MODULES", "TRUSS_PARTS", "outlines", "run_structure_demo", "stage_parts",
           "stage_structure_batch", "stage_structure_run"]
