"""The use case of ``tpods estimate batch`` (one shooting, every method), from the run to
what is printed and written: :func:`estimate_batch` runs
:func:`estimator.estimate.estimate_run`, then :func:`report_estimate` adds what the
command reports beside the fit (an implausible body, the valve dead-time scan, a fit that
did not converge or a filter that diverged) and returns a :class:`BatchReport`.

A :class:`BatchReport` holds the JSON object (``out``), the warnings (text without the
``tpods: warning:`` prefix; ``warnings`` arise before the files are written,
``late_warnings`` after), the console ``lines()``, and ``write(main, folder)`` of the result
files: estimate.json, and in a folder residuals.csv (t s, x m, y m, psi rad) with
residuals.png and poses_fit.png (least squares) or history.csv with errors.png (filters).
Nothing is printed.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from common.errors import UserError

SEGMENTS_HINT_S = 30.0
"""A single-shooting fit longer than this that does not converge points to --segments."""


@dataclass
class BatchReport:
    """An estimate (:class:`estimator.estimate.Estimate`) as ``estimate batch`` reports
    it: see the module's docstring. ``scan`` is the delay scan (or None), ``sigma`` the
    pose noise (m, rad) the residual figure marks."""

    est: Any
    out: dict[str, Any]
    warnings: list[str] = field(default_factory=list)
    late_warnings: list[str] = field(default_factory=list)
    scan: Any = None
    sigma: tuple[float, float] = (0.01, math.radians(1.0))

    def json_text(self) -> str:
        """The ``--json`` line (numpy values as numbers)."""
        from common.runwriter import json_default

        default = json_default if self.est.batch is not None else str
        return json.dumps(self.out, default=default)

    def lines(self) -> list[str]:
        """The text report."""
        from estimator.reports.estimate_text import (
            ext_lines,
            filter_lines,
            ls_lines,
            structure_body_lines,
        )

        if self.est.ext is not None:
            return ext_lines(self.est, self.out, self.est.method) + structure_body_lines(self.out)
        if self.est.filter is not None:
            return filter_lines(self.est, self.out, self.est.method)
        return ls_lines(self.est, self.out, self.scan)

    @property
    def folder_files(self) -> str | None:
        """What ``write`` adds in a folder, as ``wrote`` names it (None: no ``wrote`` line)."""
        if self.est.ext is not None:
            return None
        return ", history.csv, errors.png" if self.est.filter is not None else \
            ", residuals.csv, residuals.png, poses_fit.png"

    def write(self, main: Path, folder: Path | None) -> None:
        """The JSON object to ``main``; with a ``folder`` (else None) the tables and figures."""
        main.write_text(json.dumps(self.out, indent=2, default=str) + "\n")
        if folder is None:
            return
        if self.est.ext is not None:
            r = self.est.ext
            cols = ["t", *r.labels, *(f"sigma_{n}" for n in r.labels), "updated", "nis"]
            np.savetxt(folder / "history.csv", np.column_stack([r.t, r.x, r.sigma, r.updated, r.nis]),
                       delimiter=",", header=",".join(cols), comments="", fmt="%.10g")
        elif self.est.filter is not None:
            _write_filter(self.est, self.out, folder)
        else:
            _write_ls(self.est, folder, self.sigma)


def _write_ls(est, d: Path, sigma: tuple[float, float]) -> None:
    from estimator.reports.plots.batch import plot_poses_fit, plot_residuals

    res, run = est.batch, est.run
    np.savetxt(d / "residuals.csv", np.column_stack([res.t, res.residuals]), delimiter=",",
               header="t,res_x_m,res_y_m,res_psi_rad", comments="", fmt="%.10g")
    plot_residuals(res.t, res.residuals, d / "residuals.png", sigma_pos_m=sigma[0],
                   sigma_yaw_rad=sigma[1], title=f"Batch LS residuals: {run.path.name}")
    rows = np.searchsorted(run.pose_t, res.t)
    plot_poses_fit(res.t, run.pose[rows], res.residuals, d / "poses_fit.png",
                   title=f"Batch LS: measured poses and the fitted model, {run.path.name}")


def _write_filter(est, out: dict[str, Any], d: Path) -> None:
    from estimator.filters.ekf import STATE_NAMES
    from estimator.reports.plots.ekf import plot_error_bounds

    fe, r = est.filter, est.filter.result
    cols = ["t"] + list(STATE_NAMES) + [f"sigma_{n}" for n in STATE_NAMES] + ["updated", "nis",
                                                                               "underweighted"]
    np.savetxt(d / "history.csv", np.column_stack([r.t, r.x, r.sigma, r.updated, r.nis, r.triggered]),
               delimiter=",", header=",".join(cols), comments="", fmt="%.10g")
    plot_error_bounds(r.t, r.x[:, 6:8], r.sigma[:, 6:8], d / "errors.png",
                      (out["truth_mass_kg"], out["truth_izz_kgm2"]) if est.has_truth else None,
                      title=f"{est.method}{' (' + fe.ls_start + ')' if fe.ls else ''}: "
                            f"{est.run.path.name}")


def check_delay_scan(delay_scan: bool, estimate, method: str) -> None:
    """``--delay-scan`` re-fits the least squares with a dead time held fixed."""
    if delay_scan and estimate and "delay" in estimate:
        raise UserError("--delay-scan profiles a dead time the fit holds fixed; --estimate with "
                        "delay estimates it with the body: give one of them")
    if delay_scan and method != "ls":
        raise UserError(f"--delay-scan re-fits the batch least squares: it needs --method ls, "
                        f"not {method}")


def ls_window_warning(ls_window_s: float, span_s: float, what: str = "the run") -> str | None:
    """The warning when ``--ls-window`` covers all of ``span_s`` seconds of poses (the LS
    start then uses every pose and the filter has nothing left to add), else None."""
    if ls_window_s < span_s:
        return None
    return (f"--ls-window {ls_window_s:g} s covers all of {what} ({span_s:.3g} s "
            f"of poses): the LS start uses every pose and the filter adds nothing to it; give "
            f"--ls-window below {span_s:.3g} s, or use --method ls")


def body_warnings(est, thrust_table: str | Path | None) -> list[str]:
    """An estimated mass or Izz implausible for an air-table body, naming where the
    thrusts came from and their unit (an uninformative fit is reported as such instead)."""
    from common.thrust_table import load_thrust_table
    from estimator.batch.least_squares import body_warnings as warnings_of

    fit = est.batch if est.batch is not None else (est.filter.result if est.filter is not None
                                                   else est.ext)
    if fit is None or (est.batch is not None and not est.batch.converged and
                       "no information" in est.batch.message):
        return []
    v = est.run.structure
    if est.run.thrust_n is not None:
        source, unit = f"{est.run.path / 'thrusts.csv'} (in N)", None
    elif getattr(v, "kind", None) == "vehicle" and not v.tables():
        source, unit = f"{v.source}: its valves' force_n (in N)", None
    elif thrust_table:
        source, unit = thrust_table, load_thrust_table(thrust_table).unit
    else:
        source, unit = "the built-in Table 2", "gf"
    return warnings_of(fit.mass_kg, fit.izz_kgm2, source, unit)


def report_estimate(est, *, thrust_table: str | Path | None = None, clamp: bool = False,
                    sigma_pos_m: float = 0.01, sigma_yaw_rad: float = math.radians(1.0),
                    delay_max_ms: float | None = None, ls_window_s: float = 20.0,
                    window_given: bool = False,
                    warn: Callable[[str], None] | None = None) -> BatchReport:
    """The report of ``est``; ``delay_max_ms`` (least squares only) adds the delay scan
    over 0..``delay_max_ms`` in 11 steps. ``warn`` receives each warning of
    ``warnings`` as it arises (a long delay scan comes after the body's)."""
    rep = BatchReport(est, est.to_dict(), sigma=(sigma_pos_m, sigma_yaw_rad))
    body = body_warnings(est, thrust_table)

    def add(w: str) -> None:
        rep.warnings.append(w)
        if warn is not None:
            warn(w)

    for w in body:
        add(w)
    if est.ext is not None:
        if est.ext.diverged:
            rep.late_warnings.append(
                "the extended filter diverged (non-physical parameters or innovations far "
                "larger than their covariance); try --method ls-ekf")
        return rep
    if est.filter is not None:
        fe, r = est.filter, est.filter.result
        if fe.ls is not None and len(r.t):
            w = ls_window_warning(ls_window_s, float(r.t[-1] - r.t[0]),
                                  "the --window" if window_given else "the run")
            if w:
                add(w)
        if r.diverged:
            rep.late_warnings.append(
                "the filter diverged (non-physical parameters or innovations far larger than "
                "their covariance); try --method ls-ekf")
        elif r.inconsistent:
            rep.late_warnings.append(
                f"the filter is inconsistent (mean NIS {r.nis_tail_mean:.3g} over the last 10 % "
                "of updates, 3 expected): its sigma understates the error; try --method ls-ekf")
        return rep
    if body:
        rep.out["warnings"] = [*rep.out.get("warnings", []), *body]
    if delay_max_ms is not None:
        _delay_scan(rep, thrust_table, clamp, delay_max_ms, add)
    res = est.batch
    if not res.converged:
        hint = ("; a run this long cannot be integrated from one initial state unless the model "
                "is exact: fit it by segments (--segments auto)"
                if res.t[-1] - res.t[0] > SEGMENTS_HINT_S else "")
        rep.late_warnings.append(f"{res.message}; the estimate below is not a converged "
                                 f"solution{hint}")
    return rep


def _delay_scan(rep: BatchReport, thrust_table, clamp: bool, delay_max_ms: float,
                add: Callable[[str], None]) -> None:
    """The profile likelihood of a valve dead time on the fitted run, into
    ``out["delay_scan"]`` (and a warning when one is found)."""
    from common.thrust_table import load_thrust_table
    from estimator.batch.delay_scan import delay_warning, run_delay_scan

    grid = np.linspace(0.0, delay_max_ms * 1e-3, 11)
    rep.scan = run_delay_scan(rep.est.run, load_thrust_table(thrust_table), rep.est.batch,
                              clamp=clamp, sigma_pos_m=rep.sigma[0], sigma_yaw_rad=rep.sigma[1],
                              delays_s=grid)
    rep.out["delay_scan"] = rep.scan.to_dict()
    w = delay_warning(rep.scan)
    if w:
        add(w)
        rep.out["warnings"] = [*rep.out.get("warnings", []), w]


def estimate_batch(run_dir: str | Path, thrust_table: str | Path | None = None, *,
                   delay_scan: bool = False, delay_max_ms: float = 100.0,
                   log: Callable[[str], None] | None = None,
                   warn: Callable[[str], None] | None = None, **options: Any) -> BatchReport:
    """Estimate the run in ``run_dir`` as ``tpods estimate batch`` does (one shooting;
    ``options`` are :class:`estimator.estimate.EstimateOptions`' fields, e.g.
    ``method="ls"``, ``sigma_pos_m=0.01``; ``estimate`` defaults to None, as the command's:
    mass and Izz, a structure's centre of mass too) and report it. ``log`` as
    :func:`estimator.estimate.estimate_run`'s."""
    from estimator.estimate import estimate_run

    options.setdefault("estimate", None)

    check_delay_scan(delay_scan, options.get("estimate"), options.get("method", "ls"))
    est = estimate_run(run_dir, thrust_table, log=log, **options)
    fo = options.get("filter_options")
    return report_estimate(
        est, thrust_table=thrust_table, clamp=options.get("clamp", False),
        sigma_pos_m=options.get("sigma_pos_m", 0.01),
        sigma_yaw_rad=options.get("sigma_yaw_rad", math.radians(1.0)),
        delay_max_ms=delay_max_ms if delay_scan else None,
        ls_window_s=fo.ls_window_s if fo is not None else 20.0,
        window_given=options.get("window") is not None, warn=warn)
