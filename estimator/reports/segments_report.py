"""The use case of ``tpods estimate batch --segments LEN|auto`` and ``--thruster-health``:
:func:`fit_run_by_segments` reads a run folder, fits the whole run by multiple shooting
(:func:`estimator.shooting.fit.fit_segments`; under ``model="auto"`` every candidate
model, chosen by held-out segments; with ``thruster_health`` each thruster's efficiency
and verdict, :func:`estimator.shooting.health.thruster_health`) and returns a
:class:`SegmentsReport`: the JSON object, the warnings (text, no prefix), the console
``lines()`` and ``write(main, folder)`` of estimate.json (and, in a folder,
residuals_by_segment.png).

Times are run seconds (the poses' clock); values in SI units (kg, kg m^2, m, s); the
pose noise in m and rad. Nothing is printed; a user's error raises
:class:`common.errors.UserError` naming the command's options.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from common.errors import UserError
from estimator.shooting.segments import parse_excludes, parse_segments

MODEL_PARAMS = {None: (), "ideal": (), "friction": ("ct", "cr", "kb"),
                "friction+tilt": ("ct", "cr", "kb", "ax", "ay")}
"""The parameters each model adds to the estimated ones."""

FOLDS_TEXT = "3-fold cross-validation over segments"

_UNITS = {"mass": "kg", "izz": "kg m^2", "cx": "m", "cy": "m", "ax": "m/s^2", "ay": "m/s^2",
          "ct": "N s/m", "cr": "N m s/rad", "kb": "N m s/m", "delay": "s", "drop": "per valve"}


@dataclass
class SegmentsReport:
    """A segment fit as ``estimate batch --segments`` reports it: ``fit`` (a
    :class:`estimator.shooting.fit.SegmentFit`), the ``run`` fitted, ``out`` the JSON
    object, ``extra`` lines (thruster health, model selection), ``sigma`` the pose noise
    (m, rad) the figure marks."""

    run: Any
    fit: Any
    out: dict[str, Any]
    extra: list[str] = field(default_factory=list)
    sigma: tuple[float, float] = (0.01, math.radians(1.0))
    folder_files: str = ""

    @property
    def late_warnings(self) -> list[str]:
        """The fit's warnings, then a fit that did not converge."""
        done = [] if self.fit.converged else [
            f"{self.fit.message}; the estimate below is not a converged solution"]
        return [*self.fit.warnings, *done]

    def json_text(self) -> str:
        return json.dumps(self.out, indent=2, default=float)

    def write(self, main: Path, folder: Path | None) -> None:
        main.write_text(self.json_text() + "\n")
        if folder is not None:
            from estimator.reports.plots.segments import plot_segment_residuals

            plot_segment_residuals(self.fit, folder / "residuals_by_segment.png", sigma=self.sigma,
                                   title=f"Residuals by segment: {Path(str(self.run.path)).name}")

    def lines(self) -> list[str]:
        fit = self.fit
        lines = [f"batch least squares by segments on {self.run.path} ({len(fit.t)} poses in "
                 f"{fit.plan.n} segments of {fit.plan.length_s:g} s)",
                 f"  segment length {fit.length_note}",
                 f"  {fit.message}; {fit.iterations} iterations, {fit.elapsed_s:.2f} s"]
        for n in fit.names:
            s = fit.sigma[n]
            model = f", model {s['model']:.3g}" if "model" in s else ""
            lines.append(f"  {n:<8} = {fit.values[n]:.6g} {_UNITS.get(n, '')}  +/- {s['total']:.3g} "
                         f"(total; clustered {s['clustered']:.3g}, thrust {s['thrust']:.3g}{model}, "
                         f"noise only {s['noise']:.3g})")
        if fit.sigma_note:
            lines.append(f"  sigma: {fit.sigma_note}")
        rms = fit.rms()
        lines.append(f"  rms residuals: x {rms[0] * 100:.3f} cm, y {rms[1] * 100:.3f} cm, "
                     f"yaw {math.degrees(rms[2]):.3f} deg")
        lines += [f"  excluded {a:.2f}..{b:.2f} s: {why}" for a, b, why in fit.plan.excluded]
        lines += [f"  segments break at {t:.2f} s: {why}" for t, why in fit.plan.breaks]
        return lines + self.extra


def wants_segments(segments: str | None, exclude: Sequence[str] | None, thruster_health: bool,
                   out_vehicle: str | None) -> bool:
    """True when the options ask for the segment fit (``segments`` a length, auto, or
    none for single shooting)."""
    if out_vehicle and not thruster_health:
        raise UserError("--out-vehicle writes the verdicts of --thruster-health: add it")
    if exclude and segments is None and not thruster_health:
        raise UserError("--exclude leaves stretches out of a fit by segments: add --segments auto")
    length = parse_segments(segments) if segments is not None else None
    return thruster_health or (segments is not None and length != math.inf)


def _names(estimate, model, fixed) -> tuple[str, ...]:
    base = tuple(estimate) if estimate else ("mass", "izz", "cx", "cy")
    model = None if model == "auto" else model
    names = base + tuple(n for n in MODEL_PARAMS.get(model, ()) if n not in base)
    return tuple(n for n in names if n not in (fixed or {}))


def fit_run_by_segments(run_dir: str | Path, thrust_table: str | Path | None = None, *,
                        segments: str | None = "auto", exclude: Sequence[str] | None = None,
                        window: str | tuple | None = None, structure: Any = None,
                        model: str | None = None, estimate: Sequence[str] | None = None,
                        fixed: Mapping[str, float] | None = None,
                        initial: Mapping[str, float] | None = None, clamp: bool = False,
                        max_iter: int = 50, sigma_pos_m: float = 0.01,
                        sigma_yaw_rad: float = math.radians(1.0), thruster_health: bool = False,
                        out_vehicle: str | Path | None = None, force: bool = False,
                        method: str = "ls") -> SegmentsReport:
    """Fit the run in ``run_dir`` by segments of ``segments`` (``"5s"``, ``"auto"``,
    None: auto) leaving out ``exclude`` (``"T0:T1"`` in run seconds); ``estimate`` the
    parameters (default mass, izz, cx, cy, plus ``model``'s, less ``fixed``).
    ``thruster_health`` judges each thruster instead (``fixed["mass"]`` makes the
    efficiencies absolute) and ``out_vehicle`` then receives the vehicle file with the
    verdicts applied."""
    from common.runfolder import read_run
    from estimator.estimate.options import as_window
    from estimator.shooting.fit import fit_segments
    from estimator.shooting.health import thruster_health as health_of
    from estimator.shooting.vehicles import run_vehicle

    if method != "ls":
        raise UserError(f"--segments and --thruster-health fit by batch least squares: "
                        f"drop --method {method}")
    length = parse_segments(segments)
    excluded = parse_excludes(exclude)
    if thruster_health and model == "auto":
        raise UserError("--model auto chooses the model of the mass fit: run --thruster-health "
                        "without it")
    if out_vehicle and Path(out_vehicle).suffix != ".toml":
        raise UserError(f"--out-vehicle {out_vehicle}: give a .toml file name")
    if out_vehicle and Path(out_vehicle).exists() and not force:
        raise UserError(f"--out-vehicle {out_vehicle} exists; add --force to replace it")
    run = read_run(run_dir, structure=structure)
    w = as_window(window)
    if w != (None, None):
        run = run.window(*w)
    vehicle = run_vehicle(run, thrust_table)
    common = dict(sigma_pos_m=sigma_pos_m, sigma_yaw_rad=sigma_yaw_rad, length_s=length,
                  exclude=excluded)  # run seconds, as the poses
    initial = dict(initial or {})
    rep = SegmentsReport(run, None, {"run": str(run.path)}, sigma=(sigma_pos_m, sigma_yaw_rad))
    if thruster_health:
        fixed = dict(fixed or {})
        health = health_of(run.pose_t, run.pose, vehicle, run.cmd_t, run.duty_pct,
                           mass_kg=fixed.pop("mass", None), initial=initial, fixed=fixed, **common)
        rep.fit = health.fit
        rep.out["thruster_health"] = [t.to_dict() for t in health.thrusters]
        rep.out["health"] = health.to_dict()
        rep.extra += health.lines()
        if out_vehicle:
            rep.out["out_vehicle"] = str(write_vehicle(vehicle, health, out_vehicle, force))
            rep.extra.append(f"  wrote {rep.out['out_vehicle']} (the verdicts as each thruster's "
                             "health)")
    elif model == "auto":
        rep.fit = _auto(run, vehicle, _names(estimate, model, fixed), fixed or {}, initial, common,
                        rep)
    else:
        rep.fit = fit_segments(run.pose_t, run.pose, vehicle, run.cmd_t, run.duty_pct,
                               names=_names(estimate, model, fixed), fixed=fixed or {},
                               initial=initial, clamp=clamp, max_iter=max(max_iter, 30), **common)
    rep.fit.warnings += _jitter_warnings(run) + _body_warnings(rep.fit, vehicle, thrust_table)
    rep.out.update(rep.fit.to_dict())  # after the warnings: the JSON holds them too
    return rep


def _auto(run, vehicle, names, fixed, initial, common, rep: SegmentsReport):
    """``model="auto"``: every candidate fitted, chosen by held-out segments; the spread of
    the comparable candidates added to the total sigma where it exceeds it."""
    from estimator.shooting.select import select_model

    sel = select_model(run.pose_t, run.pose, vehicle, run.cmd_t, run.duty_pct, base=names,
                       fixed=fixed, initial=initial, **common)
    fit = sel.fits[sel.chosen]
    rep.out["model_selection"] = sel.to_dict()
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
    rep.extra.append(f"  model {sel.chosen} chosen by {FOLDS_TEXT}: held-out rms (noise units) "
                     + ", ".join(f"{n} {e:.3f}" for n, e in sel.heldout_rms.items()))
    return fit


def write_vehicle(vehicle, health, path: str | Path, force: bool) -> Path:
    """The vehicle file at ``path`` with each thruster's health the verdict of ``health``."""
    import tomli_w

    from common.outputs import ResultFile
    from common.vehicle_toml import vehicle_document

    verdict = {t.name: t.verdict for t in health.thrusters}
    new = replace(vehicle, thrusters=tuple(replace(t, health=verdict.get(t.name, t.health))
                                           for t in vehicle.thrusters))
    p = Path(path)
    out = ResultFile(p, force=force, option="--out-vehicle")
    with out.writing() as tmp:
        tmp.write_text(tomli_w.dumps(vehicle_document(new.name, new.thrusters, new.valves,
                                                      new.body, p.parent, prefix=p.stem + "_",
                                                      supplies=new.supplies)))
    return p


def _jitter_warnings(run) -> list[str]:
    """A warning when the pose intervals sit off any steady frame grid (dropped frames are
    whole multiples and do not count): each pose's time is then uncertain."""
    from common.interval_jitter import OFF_GRID_LIMIT, interval_jitter, off_grid_span

    span = off_grid_span(run.pose_t)
    if span <= OFF_GRID_LIMIT:
        return []
    j = interval_jitter(run.pose_t)
    return [f"the pose intervals jitter off any steady frame rate (5-95 %: {j['p5_s'] * 1e3:.1f}-"
            f"{j['p95_s'] * 1e3:.1f} ms around {j['median_s'] * 1e3:.1f} ms, {span * 100:.0f} % of a "
            "period off the grid): the times come from a coarse or busy clock (each pose's time "
            "uncertain by about half that spread), or are not the capture times; the fit takes "
            "them as exact"]


def _body_warnings(fit, vehicle, thrust_table) -> list[str]:
    """An implausible mass or Izz (:func:`estimator.batch.plausibility.body_warnings`),
    naming where the thrusts came from: the vehicle file's forces or its tables."""
    from estimator.batch.plausibility import body_warnings

    if "mass" not in fit.values and "izz" not in fit.values:
        return []
    tables = vehicle.tables()
    if not tables:
        source, unit = f"{vehicle.source}: its valves' force_n (in N)", None
    else:
        source, unit = (thrust_table or "the built-in Table 2"), tables[0].unit
    return body_warnings(fit.values.get("mass", 1.0), fit.values.get("izz"), source, unit)
