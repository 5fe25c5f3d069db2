"""``tpods demo``: the whole lab day on emulated devices, no hardware needed.

Stages (each writes into the report folder ``runs/demo-<timestamp>/``); the simulated
module's thruster 3 gives 4 % less thrust than the bench's nozzle (:func:`tpods.demo.stages.plant_table`):

1. **bench**: an emulated valve controller and OHAUS Scout (truth: the paper's Table 2)
   on pseudo-terminals; a characterisation session (:func:`bench.session.run_session`,
   short dwell) and its cubic fits (:func:`bench.fit.fit_steps`) -> ``thrust_table.toml``.
2. **mass**: the module weighed on the emulated balance (:mod:`calibration.mass`).
3. **bifilar**: an emulated bifilar swing of the module and its Izz from the trace
   (:func:`calibration.swing.bifilar.swing_and_estimate`).
4. **calibration**: the module as the known body (the balance's mass, the bifilar Izz): a
   translate-rotate run over Zenoh at the run's time scale and ``calibrate thrust``
   (per-thruster efficiencies) -> ``calibration/thrust_table.toml``.
5. **run**: the simulated module (:class:`tpods.plant_loop.SimulatedModule`: emulated
   valves on a pty, exact plant, 1 cm / 1 deg mocap noise, poses through the bridge over
   Zenoh); ``tpods estimate live`` (with the calibrated table) and ``tpods run play
   --input phase-sine`` as subprocesses, faster than real time on a shared lab clock
   (``--time-scale``).
6. **batch**: batch least squares on the run the live estimator recorded, with the bench
   table (before calibration, in a process of its own: :mod:`tpods.demo.fit`), the
   calibrated table (after) and the true table at the plant's own valve switch times (check).

Both flights measure how late the emulated valves switched (:func:`tpods.demo.procs.switch_lag_ms`)
and warn when the machine cannot keep up with the time scale.

It ends with a summary table (truth, balance/bifilar, live EKF, batch LS before and after
calibration; noise, thrust and total sigma, the error in total sigmas) and ``report.md`` with the figures of every stage. The folder's ``run.json`` says
``running`` until then and ``complete`` at the end (``aborted`` on Ctrl-C, ``failed`` on an
error: a partial lab day, see docs/run-format.md).

``tpods demo --structure`` is the variant for a rigid structure (stages in
:mod:`tpods.demo.structure`, report in :mod:`tpods.demo.structure_report`): two emulated
modules on a truss with a payload (``--mass``/``--izz``: each module's truth); every part
weighed on the emulated balance, the modules' Izz from emulated bifilar swings, positions
taped, and the ground truth by parts from ``tpods calibrate combine``; ``tpods run plant
--structure``, ``tpods estimate live --structure`` and ``tpods run play --structure`` as
subprocesses on one lab clock; batch least squares of m, Izz, cx, cy on the recorded run;
a summary table (truth, parts, live, batch; sigma and error in sigmas) and ``report.md``
with the figure of the structure and the centres of mass with their 95 % ellipses
(:func:`estimator.reports.plots.structure.plot_structure`). ``--no-live`` leaves the live
estimator out. ``--quick``: 40 s of lab time.

This module is the command (``register``, :func:`cmd_demo`: the stages in order, the
summary printed); the stages are in :mod:`tpods.demo.bench` (on the bench) and
:mod:`tpods.demo.stages` (the flights and the batch fits; their processes in
:mod:`tpods.demo.procs`), the figures, summary table and report in :mod:`tpods.demo.report`,
each stage's wall time (printed, in report.md, summary.json and run.json) in
:mod:`tpods.demo.timing`.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import importlib
import os
import sys
import threading
from pathlib import Path

from common.argtypes import positive_float, random_seed
from common.constants import PAPER_IZZ_KGM2, PAPER_MASS_KG
from common.errors import UserError
from common.outputs import add_force, stream_folder
from common.zenoh_net import add_zenoh_options


def register(sub) -> None:
    p = sub.add_parser("demo", help="run the lab day on emulated devices (no hardware needed)",
                       description="Thrust characterisation on emulated devices, mass and bifilar Izz, a "
                                   "simulated module run estimated live over Zenoh, batch estimation "
                                   "of the recorded run; a report under runs/.")
    p.add_argument("--out", default=None, help="report folder (default runs/demo-<timestamp>)")
    add_force(p)
    p.add_argument("--seed", type=random_seed, default=0, help="random seed (default 0)")
    p.add_argument("--mass", type=positive_float, default=PAPER_MASS_KG,
                   help=f"true mass, kg (default {PAPER_MASS_KG})")
    p.add_argument("--izz", type=positive_float, default=PAPER_IZZ_KGM2,
                   help="true Izz, kg m^2 (default 3.78e-3, the paper's module)")
    p.add_argument("--duration", type=positive_float, default=120.0,
                   help="simulated run, lab seconds (default 120, as in the paper)")
    p.add_argument("--time-scale", type=positive_float, default=2.0,
                   help="the simulated run goes this many times faster than real time (default 2)")
    p.add_argument("--method", choices=("ekf", "ls-ekf"), default="ls-ekf",
                   help="live estimator method (default ls-ekf, the paper's LS-initialised EKF)")
    p.add_argument("--quick", action="store_true",
                   help="fewer duty steps and a short run (a smoke test, about a minute)")
    p.add_argument("--structure", action="store_true",
                   help="the structure variant: two emulated modules on a truss, the "
                        "parts' ground truth from calibrate combine, live and batch estimates of "
                        "mass, Izz and the centre of mass (--mass/--izz: each module's truth)")
    p.add_argument("--vehicle", default=None, metavar="FILE",
                   help="the vehicle variant: the module run on a vehicle.toml (one "
                        "emulated N-channel driver, pulses on its valves, its valve timing), "
                        "live and batch estimates (--mass/--izz: the vehicle's truth); no "
                        "calibration stages")
    p.add_argument("--no-live", action="store_true",
                   help="with --structure: no live estimator; batch LS on the poses the demo "
                        "records itself and the player's commands")
    add_zenoh_options(p)
    p.set_defaults(func=cmd_demo)


def cmd_demo(args: argparse.Namespace) -> int:
    """``tpods demo``: the stages in order, the summary table, report.md, summary.json."""
    # its processes share the cores: one OpenBLAS thread each (its pool spins at start-up
    # and competes with the fits that run side by side; numbers unchanged)
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    if args.vehicle is not None:
        return _vehicle_demo(args)
    if args.no_live and not args.structure:
        raise UserError("--no-live goes with --structure (the plain demo's run is the live run)")
    if args.structure and not args.no_live and args.method != "ls-ekf":
        raise UserError("--structure is estimated live with --method ls-ekf only (from the "
                        "structure's geometric start the EKF alone diverges)")
    if args.quick:
        args.duration = min(args.duration, 40.0)
    if args.time_scale > 4:
        print("tpods: warning: at time scales above ~2-4 thread scheduling on a busy machine "
              "shifts the emulated valve switches by several lab milliseconds (a bias on Izz)",
              file=sys.stderr)
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    out = stream_folder(Path("runs") / f"demo-{stamp}" if args.out is None else args.out,
                        force=args.force, command="tpods demo")
    from common.runwriter import run_status  # lazy: numpy; keeps tpods --help fast

    # run.json: "running" until the end, then "complete" (or "aborted"/"failed": the
    # folder holds a partial lab day; a kill leaves "running"), with each stage's wall time
    if args.structure:
        # its plant, estimator and player are processes of their own: SIGTERM (and SIGINT,
        # also when started in the background) unwinds, so the player closes every valve and
        # every process is stopped; run.json says "failed" with "terminated (SIGTERM)"
        from bench.session import Terminated, sigterm_raises
        from tpods.demo.structure import run_structure_demo  # lazy: the estimator, Zenoh

        try:
            with sigterm_raises(), run_status(out / "run.json", "lab-day-demo-structure",
                                              seed=args.seed, quick=args.quick,
                                              duration_s=args.duration,
                                              time_scale=args.time_scale) as meta:
                return run_structure_demo(args, out, meta)
        except Terminated:
            print("tpods: terminated; every module's valves closed, the demo's processes stopped",
                  file=sys.stderr)
            return 143
    with run_status(out / "run.json", "lab-day-demo", seed=args.seed, quick=args.quick,
                    duration_s=args.duration, time_scale=args.time_scale) as meta:
        return _stages(args, out, meta)


def _vehicle_demo(args: argparse.Namespace) -> int:
    """``tpods demo --vehicle F`` (:mod:`tpods.demo.vehicle`): its checks, folder, run.json."""
    if args.structure or args.no_live:
        raise UserError("--vehicle is a variant of its own: without --structure and --no-live")
    if args.method != "ls-ekf":
        raise UserError("--vehicle is estimated live with --method ls-ekf only (from the "
                        "vehicle's geometric start the EKF alone diverges)")
    from common.vehicle import Vehicle

    Vehicle.load(args.vehicle)  # a bad file: one line, before the folder is made
    if args.quick:
        args.duration = min(args.duration, 40.0)
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    out = stream_folder(Path("runs") / f"demo-{stamp}" if args.out is None else args.out,
                        force=args.force, command="tpods demo")
    from bench.session import Terminated, sigterm_raises
    from common.runwriter import run_status
    from tpods.demo.vehicle import run_vehicle_demo  # lazy: the estimator, Zenoh

    try:
        with sigterm_raises(), run_status(out / "run.json", "lab-day-demo-vehicle",
                                          seed=args.seed, quick=args.quick,
                                          duration_s=args.duration,
                                          time_scale=args.time_scale) as meta:
            return run_vehicle_demo(args, out, meta)
    except Terminated:
        print("tpods: terminated; the valves closed, the demo's processes stopped",
              file=sys.stderr)
        return 143


def _stages(args: argparse.Namespace, out: Path, meta: dict) -> int:
    """The stages of :func:`cmd_demo` into ``out``, the summary table and the report; each
    stage's wall time into ``meta`` (run.json's ``timings_s``)."""
    os.environ.setdefault("MPLBACKEND", "Agg")
    from tpods.demo.side import SideWork  # light: the workers import the heavy modules

    # two workers import the estimator and matplotlib while this process does and the
    # characterisation dwells; figures and two batch fits run there beside the stages
    side = SideWork()
    try:
        # lazy: keeps tpods --help fast (the stages import the estimator, Zenoh, matplotlib)
        from tpods.demo.timing import StageTimes

        return _stages_with(args, out, StageTimes(meta), side)
    finally:
        side.close()


def _stages_with(args: argparse.Namespace, out: Path, times, side) -> int:
    """:func:`_stages` with the side workers ``side`` (:class:`tpods.demo.side.SideWork`)."""
    from tpods.demo.bench import mass_and_bifilar, stage_bench  # light: the bench's modules
    from tpods.demo.timing import print_summary

    # the bench fit's, the flights', the batch stage's and the report's modules (pandas, the
    # estimator, Zenoh, matplotlib: 1-2 s) are imported by a thread while the
    # characterisation dwells
    later = _import_beside("bench.fit", "tpods.demo.stages", "tpods.demo.report")
    meta = times.meta
    print(f"TPODS lab day on emulated devices -> {out}")

    # the balance and the pendulum (their own emulated devices) in a side process, beside
    # the characterisation; their results are printed in their place below
    ground = side.submit("mass + bifilar (beside characterisation)", mass_and_bifilar, out,
                         args.mass, args.izz, args.seed)
    with times.stage("1/6 thrust characterisation (emulated valve controller + OHAUS Scout)",
                     "characterisation + fit"):
        bench = stage_bench(out, args.seed, args.quick, side)
    times.paced("characterisation + fit", bench["planned_s"])
    later.join()
    from tpods.demo.report import plot_run, summary_rows, table_lines, write_report, write_summary
    from tpods.demo.stages import side_fits, stage_batch, stage_calibrate, stage_run

    with times.stage("2/6 mass on the balance", "mass"):
        mass, text_mass, bif, text_bif = ground.result()
        print(text_mass, end="")

    with times.stage("3/6 bifilar pendulum", "bifilar"):
        print(text_bif, end="")

    with times.stage("4/6 in-situ thrust calibration: the module as the known body",
                     "calibration run + fit"):
        cal = stage_calibrate(out, args, bench, mass, bif)
    times.paced("calibration run + fit", cal["live"]["duration_lab_s"] / cal["live"]["time_scale"])

    with times.stage("5/6 simulated module run over Zenoh, estimated live (calibrated table)",
                     "module run (live)"):
        # the batch stage's fits start once the run's recording is sealed, beside the live
        # estimator's final fit
        early: dict = {}
        live = stage_run(out, args, cal["table_path"], on_recorded=lambda _d: early.update(
            side_fits(out, bench["table"], side, "beside the estimator's end and batch")))
        print(f"   live {live.get('method')} ({live.get('phase')}): m = {live['mass_kg']:.5f} +- "
              f"{live['mass_sigma_kg']:.2g} kg, Izz = {live['izz_kgm2']:.6g} +- "
              f"{live['izz_sigma_kgm2']:.2g} kg m^2 (total sigma)")
    times.paced("module run (live)", args.duration / args.time_scale)

    with times.stage("6/6 batch least squares on the recorded run, before and after calibration",
                     "batch"):
        truth = (args.mass, args.izz)
        run_figs = side.submit("run figures (beside batch)", plot_run, out,
                               {k: live[k] for k in ("truth_t", "truth_s", "method") if k in live},
                               truth)
        batch = stage_batch(out, bench["table"], cal["table"], side, early or None)

    with times.stage(None, "figures"):
        bench["figures"] = bench["figures"].result()  # drawn beside the next stages
        figs = bench["figures"] + bif["figures"] + run_figs.result() + batch["figures"]
        rows = summary_rows(truth, mass, bif, live, batch)
    times.beside(side.side_s)
    meta["timings_s"] = timings = times.timings()  # the total with the figures
    report = write_report(out, args, rows, bench, mass, bif, live, batch, figs, times, cal)
    write_summary(out, args, rows, bench, live, batch, timings, cal)
    print_summary("summary (truth: the simulated module; sigma = total: noise + thrust table; "
                  "error in total sigmas)", table_lines(rows), times,
                  f"simulated run: {args.duration:g} s of lab time at time scale "
                  f"{args.time_scale:g}", report, len(figs))
    return 0


def _import_beside(*modules: str) -> threading.Thread:
    """A thread that imports ``modules`` (started at once; ``join`` it before using them).
    Beside the characterisation: its emulated devices are threads of this process that
    mostly sleep between readings, and the interpreter lock passes between threads every
    few milliseconds (the planned windows are 150 ms). An import that fails here fails
    again, with its message, where the module is used."""
    def run() -> None:
        for m in modules:
            try:
                importlib.import_module(m)
            except Exception:  # noqa: BLE001 - raised again by the import that needs it
                return

    t = threading.Thread(target=run, name="tpods-demo-imports", daemon=True)
    t.start()
    return t
