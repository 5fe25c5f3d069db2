"""``tpods estimate batch RUN --segments LEN|auto`` and ``--thruster-health``: a whole run
fitted by multiple shooting (:mod:`estimator.shooting`); a thin shell that reads the run,
calls the use case and prints or writes what it returns."""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import replace
from pathlib import Path

from common.errors import UserError
from estimator.shooting.segments import parse_excludes, parse_segments

MODEL_PARAMS = {None: (), "ideal": (), "friction": ("ct", "cr", "kb"),
                "friction+tilt": ("ct", "cr", "kb", "ax", "ay")}


def add_options(p: argparse.ArgumentParser) -> None:
    """The segment fit's options of ``tpods estimate batch``."""
    p.add_argument("--segments", default=None, metavar="LEN|auto|none",
                   help="fit the run as shooting segments, each from its own initial state with "
                        "the physical parameters shared: a length (5s), auto (chosen from the "
                        "data) or none (single shooting, the default); for whole real runs")
    p.add_argument("--exclude", action="append", default=None, metavar="T0:T1",
                   help="with --segments: leave out the poses in T0..T1 (run seconds; repeatable)")
    p.add_argument("--thruster-health", action="store_true",
                   help="each thruster's efficiency (relative to the others; absolute with "
                        "--fixed mass=KG) and a verdict: ok, weak, dead, reversed, stuck-open "
                        "(fits by segments; --segments auto unless given)")
    p.add_argument("--out-vehicle", default=None, metavar="NEW.toml",
                   help="with --thruster-health: write the vehicle file with the verdicts "
                        "applied (a dead thruster gives no thrust in every estimator)")


def wanted(args: argparse.Namespace) -> bool:
    """True when the command asks for the segment fit."""
    if args.out_vehicle and not args.thruster_health:
        raise UserError("--out-vehicle writes the verdicts of --thruster-health: add it")
    if args.exclude and args.segments is None and not args.thruster_health:
        raise UserError("--exclude leaves stretches out of a fit by segments: add --segments auto")
    length = parse_segments(args.segments) if args.segments is not None else None
    return args.thruster_health or (args.segments is not None and length != math.inf)


def _run_and_vehicle(args):
    from common.runfolder import read_run
    from estimator.estimate.options import as_window
    from estimator.shooting.vehicles import run_vehicle

    run = read_run(args.run_dir, structure=args.structure)
    w = as_window(args.window)
    if w != (None, None):
        run = run.window(*w)
    return run, run_vehicle(run, args.thrust_table)


def _names(args) -> tuple[str, ...]:
    base = tuple(args.estimate) if args.estimate else ("mass", "izz", "cx", "cy")
    model = None if args.model == "auto" else args.model
    names = base + tuple(n for n in MODEL_PARAMS.get(model, ()) if n not in base)
    return tuple(n for n in names if n not in (args.fixed or {}))


def _auto(args, run, vehicle, initial, common, out):
    """``--model auto``: every candidate fitted, chosen by held-out segments; the spread of
    the comparable candidates added to the total sigma where it exceeds it."""
    from estimator.shooting.select import select_model

    sel = select_model(run.pose_t, run.pose, vehicle, run.cmd_t, run.duty_pct, base=_names(args),
                       fixed=args.fixed or {}, initial=initial, **common)
    fit = sel.fits[sel.chosen]
    out["model_selection"] = sel.to_dict()
    for k, (a, b) in sel.spread.items():
        half = 0.5 * (b - a)
        sig = fit.sigma.get(k)
        if sig is not None and half > sig["total"]:
            sig["model"] = half
            sig["total"] = math.hypot(sig["total"], half)
            fit.warnings.append(
                f"the {k} depends on the model: {a:.4g}..{b:.4g} across the candidates that "
                f"predict held-out segments about as well as {sel.chosen}; half that range is in "
                "the total sigma")
    return fit, [f"  model {sel.chosen} chosen by {FOLDS_TEXT}: held-out rms (noise units) "
                 + ", ".join(f"{n} {e:.3f}" for n, e in sel.heldout_rms.items())]


FOLDS_TEXT = "3-fold cross-validation over segments"


def cmd_segments(args: argparse.Namespace) -> int:
    """The segment fit (and the thruster health) of ``tpods estimate batch``."""
    from estimator.shooting.fit import fit_segments
    from estimator.shooting.health import thruster_health

    if args.method != "ls":
        raise UserError(f"--segments and --thruster-health fit by batch least squares: "
                        f"drop --method {args.method}")
    length = parse_segments(args.segments)
    exclude = parse_excludes(args.exclude)
    if args.thruster_health and args.model == "auto":
        raise UserError("--model auto chooses the model of the mass fit: run --thruster-health "
                        "without it")
    if args.out_vehicle and Path(args.out_vehicle).suffix != ".toml":
        raise UserError(f"--out-vehicle {args.out_vehicle}: give a .toml file name")
    if args.out_vehicle and Path(args.out_vehicle).exists() and not args.force:
        raise UserError(f"--out-vehicle {args.out_vehicle} exists; add --force to replace it")
    run, vehicle = _run_and_vehicle(args)
    common = dict(sigma_pos_m=args.sigma_pos, sigma_yaw_rad=math.radians(args.sigma_yaw_deg),
                  length_s=length, exclude=exclude)  # run seconds, as the poses
    initial = dict(args.initial or {})
    out: dict = {"run": str(run.path)}
    lines: list[str] = []
    if args.thruster_health:
        fixed = dict(args.fixed or {})
        rep = thruster_health(run.pose_t, run.pose, vehicle, run.cmd_t, run.duty_pct,
                              mass_kg=fixed.pop("mass", None), initial=initial, fixed=fixed,
                              **common)
        fit = rep.fit
        out["thruster_health"] = [t.to_dict() for t in rep.thrusters]
        out["health"] = rep.to_dict()
        lines += rep.lines()
        if args.out_vehicle:
            out["out_vehicle"] = str(_write_vehicle(vehicle, rep, args.out_vehicle, args.force))
            lines.append(f"  wrote {out['out_vehicle']} (the verdicts as each thruster's health)")
    elif args.model == "auto":
        fit, more = _auto(args, run, vehicle, initial, common, out)
        lines += more
    else:
        fit = fit_segments(run.pose_t, run.pose, vehicle, run.cmd_t, run.duty_pct,
                           names=_names(args), fixed=args.fixed or {}, initial=initial,
                           clamp=args.clamp, max_iter=max(args.max_iter, 30), **common)
    _jitter_warning(run, fit)
    _body_warning(fit, vehicle, args)
    out.update(fit.to_dict())  # after the warnings: --json holds them too
    if args.out_folder is not None:
        _write_outputs(args, out, fit, run)
    for w in fit.warnings:
        print(f"tpods: warning: {w}", file=sys.stderr)
    if not fit.converged:
        print(f"tpods: warning: {fit.message}; the estimate below is not a converged solution",
              file=sys.stderr)
    if args.json:
        print(json.dumps(out, indent=2, default=float))
        return 0
    _print(run, fit, lines)
    if args.out_folder is not None:
        print(f"  wrote {args.out_folder.main}")
    return 0


def _print(run, fit, lines) -> None:
    print(f"batch least squares by segments on {run.path} ({len(fit.t)} poses in {fit.plan.n} "
          f"segments of {fit.plan.length_s:g} s)")
    print(f"  segment length {fit.length_note}")
    print(f"  {fit.message}; {fit.iterations} iterations, {fit.elapsed_s:.2f} s")
    units = {"mass": "kg", "izz": "kg m^2", "cx": "m", "cy": "m", "ax": "m/s^2", "ay": "m/s^2",
             "ct": "N s/m", "cr": "N m s/rad", "kb": "N m s/m", "delay": "s", "drop": "per valve"}
    for n in fit.names:
        s = fit.sigma[n]
        model = f", model {s['model']:.3g}" if "model" in s else ""
        print(f"  {n:<8} = {fit.values[n]:.6g} {units.get(n, '')}  +/- {s['total']:.3g} (total; "
              f"clustered {s['clustered']:.3g}, thrust {s['thrust']:.3g}{model}, noise only "
              f"{s['noise']:.3g})")
    if fit.sigma_note:
        print(f"  sigma: {fit.sigma_note}")
    rms = fit.rms()
    print(f"  rms residuals: x {rms[0] * 100:.3f} cm, y {rms[1] * 100:.3f} cm, "
          f"yaw {math.degrees(rms[2]):.3f} deg")
    for a, b, why in fit.plan.excluded:
        print(f"  excluded {a:.2f}..{b:.2f} s: {why}")
    for t, why in fit.plan.breaks:
        print(f"  segments break at {t:.2f} s: {why}")
    for line in lines:
        print(line)


def _write_vehicle(vehicle, rep, path: str, force: bool) -> Path:
    from common.outputs import ResultFile
    from common.vehicle_toml import vehicle_document

    verdict = {t.name: t.verdict for t in rep.thrusters}
    new = replace(vehicle, thrusters=tuple(replace(t, health=verdict.get(t.name, t.health))
                                           for t in vehicle.thrusters))
    p = Path(path)
    import tomli_w

    out = ResultFile(p, force=force, option="--out-vehicle")
    with out.writing() as tmp:
        tmp.write_text(tomli_w.dumps(vehicle_document(new.name, new.thrusters, new.valves,
                                                      new.body, p.parent, prefix=p.stem + "_",
                                                      supplies=new.supplies)))
    return p


def _jitter_warning(run, fit) -> None:
    """A warning when the pose intervals sit off any steady frame grid (dropped frames are
    whole multiples and do not count): each pose's time is then uncertain."""
    from common.interval_jitter import OFF_GRID_LIMIT, interval_jitter, off_grid_span

    span = off_grid_span(run.pose_t)
    if span <= OFF_GRID_LIMIT:
        return
    j = interval_jitter(run.pose_t)
    fit.warnings.append(
        f"the pose intervals jitter off any steady frame rate (5-95 %: {j['p5_s'] * 1e3:.1f}-"
        f"{j['p95_s'] * 1e3:.1f} ms around {j['median_s'] * 1e3:.1f} ms, {span * 100:.0f} % of a "
        "period off the grid): the times come from a coarse or busy clock (each pose's time "
        "uncertain by about half that spread), or are not the capture times; the fit takes "
        "them as exact")


def _body_warning(fit, vehicle, args) -> None:
    """An implausible mass or Izz (:func:`estimator.batch.plausibility.body_warnings`),
    naming where the thrusts came from: the vehicle file's forces or its tables."""
    from estimator.batch.plausibility import body_warnings

    if "mass" not in fit.values and "izz" not in fit.values:
        return
    tables = vehicle.tables()
    if not tables:
        source, unit = f"{vehicle.source}: its valves' force_n (in N)", None
    else:
        source, unit = (args.thrust_table or "the built-in Table 2"), tables[0].unit
    fit.warnings += body_warnings(fit.values.get("mass", 1.0), fit.values.get("izz"),
                                  source, unit)


def _write_outputs(args, out, fit, run) -> None:
    from estimator.reports.plots.segments import plot_segment_residuals

    with args.out_folder.writing_main() as (main, d):
        main.write_text(json.dumps(out, indent=2, default=float) + "\n")
        if d is not None:
            plot_segment_residuals(fit, d / "residuals_by_segment.png",
                                   sigma=(args.sigma_pos, math.radians(args.sigma_yaw_deg)),
                                   title=f"Residuals by segment: {Path(str(run.path)).name}")
