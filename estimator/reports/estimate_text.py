"""The text of the estimate results, as ``tpods estimate batch`` and ``estimate crlb``
print them: lists of lines (two-space indented), built from a result and its JSON object.

- :func:`budget_lines`, :func:`filter_budget`, :func:`centre_of_mass_lines`,
  :func:`structure_body_lines`: pieces shared by several results (the uncertainty budget
  table; a structure's centre of mass and [body] knowledge).
- :func:`ls_lines` (batch least squares), :func:`filter_lines` (EKF, LS-EKF, ideal
  model), :func:`ext_lines` (the extended-state filters): an
  :class:`estimator.estimate.Estimate`.
- :func:`crlb_lines` (a :class:`estimator.estimate.Bound`) and :func:`inputs_bound_lines`
  (the joint bound with a vehicle's valve parameters).

Units as printed: kg, kg m^2, m, s; rms residuals in cm and deg.
"""

from __future__ import annotations

import math
from typing import Any

_UNITS = {"mass": "kg", "izz": "kg m^2", "ct": "N s/m", "cr": "N m s", "kb": "N m s/m",
          "ax": "m/s^2", "ay": "m/s^2", "cx": "m", "cy": "m", "delay": "s", "drop": "per valve"}


def budget_lines(budget: dict[str, tuple[float, float, float]]) -> list[str]:
    """The uncertainty budget as a small table (1 sigma: noise, thrust table, total); no
    lines when the thrust part is zero everywhere (the total is the noise part)."""
    if not any(t for _, t, _ in budget.values()):
        return []
    lines = [f"  {'uncertainty (1 sigma)':<22} {'noise':>10} {'thrust':>10} {'total':>10}"]
    for name, (n, t, tot) in budget.items():
        lab = f"{'Izz' if name == 'izz' else name} ({_UNITS.get(name, '')})"
        lines.append(f"    {lab:<20} {n:10.3g} {t:10.3g} {tot:10.3g}")
    return lines


def filter_budget(out: dict[str, Any]) -> dict[str, tuple[float, float, float]]:
    """The budget of a filter estimate's JSON object (keys of ``filter_thrust_budget``)."""
    b = {}
    for name, unit in (("mass", "kg"), ("izz", "kgm2")):
        if f"{name}_sigma_noise_{unit}" in out and out[f"{name}_sigma_{unit}"] is not None:
            b[name] = (out[f"{name}_sigma_noise_{unit}"], out[f"{name}_sigma_thrust_{unit}"],
                       out[f"{name}_sigma_{unit}"])
    return b


def centre_of_mass_lines(out: dict[str, Any]) -> list[str]:
    """A structure's estimated centre of mass and its Izz about the tracked origin (no lines
    for a single module's estimate)."""
    if "com_x_m" not in out:
        return []
    return [f"  centre of mass ({out['com_x_m']:+.5f} +/- {out['com_x_sigma_m']:.2g}, "
            f"{out['com_y_m']:+.5f} +/- {out['com_y_sigma_m']:.2g}) m in the tracked frame of "
            f"{'vehicle' if 'vehicle' in out else 'structure'} {out['structure']!r}; Izz above is "
            "about it",
            f"  Izz about the tracked origin = {out['izz_origin_kgm2']:.6g} +/- "
            f"{out['izz_origin_sigma_kgm2']:.3g} kg m^2"]


def structure_body_lines(out: dict[str, Any]) -> list[str]:
    """The text lines on a structure's [body] values used as known (fixed) or as priors
    (the JSON's ``known_from_structure``, ``prior_from_structure``)."""
    lines = []
    if out.get("known_from_structure"):
        lines.append("  known from structure.toml [body] (fixed, not estimated): " + ", ".join(
            f"{n} {v:.6g}" for n, v in out["known_from_structure"].items())
            + "; --estimate NAME,... estimates one")
    if out.get("prior_from_structure"):
        lines.append("  prior from structure.toml [body] (in the estimate): " + ", ".join(
            f"{n} {p['mean']:.6g} +/- {p['sigma']:.3g}"
            for n, p in out["prior_from_structure"].items()))
    return lines


def _truth_line(out: dict[str, Any]) -> str:
    return (f"  truth: mass {out['truth_mass_kg']:.6g} kg (error {out['mass_rel_error'] * 100:+.3f} %), "
            f"Izz {out['truth_izz_kgm2']:.6g} (error {out['izz_rel_error'] * 100:+.3f} %)")


def ls_lines(est, out: dict[str, Any], scan=None) -> list[str]:
    """Batch least squares (``est.batch``) with its JSON object ``out`` and the delay
    scan ``scan`` (or None)."""
    res, run = est.batch, est.run
    what = "1 sigma, total" if res.cov_thrust is not None else "1 sigma, noise only"
    lines = [f"batch least squares on {run.path} ({len(res.t)} poses, "
             f"t = {res.t[0]:.3f}..{res.t[-1]:.3f} s)",
             f"  {res.message}; {res.iterations} iterations, horizons "
             f"{', '.join(f'{h:.1f}' for h in res.stages)} s, {res.elapsed_s:.2f} s",
             f"  mass  = {res.mass_kg:.6g} kg      +/- {res.mass_sigma_kg:.3g} ({what})",
             f"  Izz   = {res.izz_kgm2:.6g} kg m^2  +/- {res.izz_sigma_kgm2:.3g} ({what})",
             *budget_lines(res.budget())]
    if not math.isnan(res.corr_mass_izz):
        lines.append(f"  corr(mass, Izz) = {res.corr_mass_izz:+.3f}")
    for n in res.names:
        if n not in ("mass", "izz"):
            i = 6 + res.names.index(n)
            lines.append(f"  {n:<5} = {res.z0[i]:.6g} +/- {res.sigma[i]:.3g}")
    lines += centre_of_mass_lines(out) + structure_body_lines(out)
    rms = res.rms_residuals()
    lines.append(f"  rms residuals: x {rms[0] * 100:.3f} cm, y {rms[1] * 100:.3f} cm, "
                 f"yaw {math.degrees(rms[2]):.3f} deg")
    if "truth_mass_kg" in out:
        lines.append(_truth_line(out))
    if "crlb_mass_sigma_kg" in out:
        lines.append(f"  CRLB at truth: mass {out['crlb_mass_sigma_kg']:.3g} kg, "
                     f"Izz {out['crlb_izz_sigma_kgm2']:.3g} kg m^2")
    if scan is not None:
        lines.append(f"  delay scan: {scan.describe()}")
    return lines


def filter_lines(est, out: dict[str, Any], method: str) -> list[str]:
    """An ideal-model filter (``est.filter``) run as ``method`` (ekf or ls-ekf)."""
    fe, run, r = est.filter, est.run, est.filter.result
    label = method + (f" ({fe.ls_start}, LS window {fe.ls_window_s:g} s)" if fe.ls else "")
    lines = [f"{label} on {run.path} ({len(r.t)} poses, t = {r.t[0]:.3f}..{r.t[-1]:.3f} s)"]
    if fe.ls is not None:
        lines.append(f"  LS start: mass {fe.ls.mass_kg:.6g} +/- {fe.ls.mass_sigma_kg:.3g} kg, "
                     f"Izz {fe.ls.izz_kgm2:.6g} +/- {fe.ls.izz_sigma_kgm2:.3g} kg m^2")
    lines += [f"  mass  = {r.mass_kg:.6g} kg      +/- {out['mass_sigma_kg']:.3g} (1 sigma)",
              f"  Izz   = {r.izz_kgm2:.6g} kg m^2  +/- {out['izz_sigma_kgm2']:.3g} (1 sigma)",
              *budget_lines(filter_budget(out)),
              f"  mean NIS {out['nis_mean']:.3g} (3 expected), "
              f"{out['underweighted_updates']} underweighted updates"]
    if est.has_truth:
        lines += [_truth_line(out),
                  f"  RMSE over the run: mass {out['rmse_mass_kg']:.4g} kg, "
                  f"Izz {out['rmse_izz_kgm2']:.4g} kg m^2"]
    return lines


def ext_lines(est, out: dict[str, Any], method: str) -> list[str]:
    """An extended-state filter (``est.ext``: friction, yaw bias, tilt) run as ``method``."""
    from estimator.filters.ext import SIGMA0

    r = est.ext
    lines = [f"{method} with --model {est.model} on {est.run.path} ({len(r.t)} poses)"]
    for n in r.names:
        v, s = r.final(n)
        lines.append(f"  {n:<5} = {v:.6g} +/- {s:.3g} (1 sigma, noise; prior sigma {SIGMA0[n]:g})")
    # a structure: its centre of mass as the batch least squares prints it
    lines += budget_lines(filter_budget(out)) + centre_of_mass_lines(out)
    if "truth_mass_kg" in out:
        lines.append(f"  RMSE over the run: mass {out['rmse_mass_kg']:.4g} kg, "
                     f"Izz {out['rmse_izz_kgm2']:.4g} kg m^2")
    return lines


def crlb_lines(b, out: dict[str, Any], run_dir: str) -> list[str]:
    """The bound ``b`` (:class:`estimator.estimate.Bound`) of the sequence ``run_dir``
    with its JSON object ``out`` (the thrust note, when not included, is a warning: not
    here)."""
    from estimator.plant.parameter_sets import PARAM_UNITS

    c = b.crlb
    lines = [f"Cramér-Rao bound of {run_dir} ({b.kind}, {c.n_poses} poses over "
             f"{out['duration_s']:.1f} s; plant from {b.plant_source}: m = {b.mass_kg:g} kg, "
             f"Izz = {b.izz_kgm2:g} kg m^2)"]
    if "mass" in c.names:
        lines.append(f"  mass  sigma >= {c.mass_sigma_kg:.4g} kg      "
                     f"({out['crlb_mass_rel'] * 100:.4f} %)")
    if "izz" in c.names:
        lines.append(f"  Izz   sigma >= {c.izz_sigma_kgm2:.4g} kg m^2  "
                     f"({out['crlb_izz_rel'] * 100:.4f} %)")
    corr = out["crlb_corr_mass_izz"]
    lines.append((f"  correlation {corr:+.3f}, " if corr is not None else "  ")
                 + f"log det(information) {c.logdet:.3f}")
    lines += structure_body_lines(out)
    if out["thrust_uncertainty"]["included"] and {"mass", "izz"} <= set(c.names):
        lines.append(
            f"  with the thrust table's uncertainty: mass sigma {out['mass_sigma_total_kg']:.4g} kg "
            f"(thrust part {out['mass_sigma_thrust_kg']:.4g}), Izz sigma "
            f"{out['izz_sigma_total_kgm2']:.4g} kg m^2 (thrust part {out['izz_sigma_thrust_kgm2']:.4g})")
    # the other parameters: the extended model's, or a structure's beside a known mass/Izz
    named = zip(c.names[2:], c.sigma[2:], strict=True) if c.names[:2] == ("mass", "izz") else \
        ((n, s) for n, s in zip(c.names, c.sigma, strict=True) if n not in ("mass", "izz"))
    return lines + [f"  {n:<5} sigma >= {s:.4g} {PARAM_UNITS[n]}" for n, s in named]


def _inputs_unit(name: str) -> str:
    from estimator.plant.parameter_sets import PARAM_UNITS

    units = {"mass": "kg", "izz": "kg m^2", "cx": "m", "cy": "m", "delay": "s",
             "drop": "per other open valve"}
    return units.get("drop" if name.startswith("drop.") else name, PARAM_UNITS.get(name, ""))


def inputs_bound_lines(out: dict[str, Any], run_dir: str, plant_source: str) -> list[str]:
    """The joint bound of a vehicle's body and valve parameters
    (:func:`estimator.estimate.vehicle_bound.bound_with_inputs`, its JSON object ``out``)."""
    lines = [f"Cramér-Rao bound of {run_dir} (recorded, {out['n_poses']} poses over "
             f"{out['duration_s']:.1f} s; plant from {plant_source}), jointly with the valves"]
    for n, s in out["crlb_sigma"].items():
        at = f"at {out['at'][n]:.6g} {_inputs_unit(n)}"
        if s is None:
            lines.append(f"  {n:<5} not informed by this run ({out['not_informed'][n]}); {at}")
        else:
            total = out.get("crlb_sigma_total", {}).get(n)
            with_f = f" (with the stated forces {total:.4g})" if total is not None else ""
            lines.append(f"  {n:<5} sigma >= {s:.4g} {_inputs_unit(n)}{with_f}, {at}")
    if out["crlb_corr_mass_izz"] is not None:
        lines.append(f"  correlation(mass, Izz) {out['crlb_corr_mass_izz']:+.3f}, "
                     f"log det(information) {out['logdet_info']:.3f}")
    return lines
