"""The helpers of a structure run in the estimates: is a run one, its
:class:`common.structure.Structure`, its JSON keys (centre of mass, Izz about the tracked
origin: :func:`structure_keys`, :func:`com_keys`) and the thrust-table part of its fit's
covariance (:func:`_structure_consider`)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from common.errors import UserError
from common.layout_files import as_layout, folder_layout
from common.runfolder import Run
from common.thrust_table import ThrustTable
from estimator.batch.least_squares import BatchResult


def _is_structure_run(run: Run | str | Path, structure) -> bool:
    """True for a structure run: ``structure`` given, the Run has one, or its folder holds
    structure.toml (known before the run is read)."""
    if structure is not None:
        return True
    if isinstance(run, Run):
        return run.structure is not None
    return folder_layout(run) is not None


def _structure_of(run: Run | str | Path, structure):
    """The Structure of a structure run (``structure`` given, the Run's or its folder's)."""
    if structure is not None:
        return as_layout(structure)
    if isinstance(run, Run):
        return run.structure
    return as_layout(folder_layout(run))


def _with_structure(run: Run, structure) -> Run:
    """``run`` read as a structure run of ``structure`` (a Structure or its TOML file)."""
    s = as_layout(structure)
    if run.duty_pct is not None and run.duty_pct.shape[-1] != s.n_channels:
        raise UserError(f"{run.path / 'commands.csv'}: {run.duty_pct.shape[-1]} duty columns; "
                        f"structure {s.name!r} has {s.n_channels} channels")
    return replace(run, structure=s)


def _structure_consider(res: BatchResult, run: Run, table: ThrustTable, clamp: bool,
                        sigma_pos_m: float, sigma_yaw_rad: float) -> None:
    """The thrust-table part of a structure fit's covariance: every module's table
    uncertainty through the virtual thrusts (:meth:`common.runfolder.Run.thrust_sensitivity`),
    as :func:`estimator.batch.least_squares.estimate_run` does for one module."""
    from estimator.batch.consider import NO_UNCERTAINTY, THRUSTS_GIVEN, batch_consider

    if not np.all(np.isfinite(res.sigma)):
        return  # an uninformative fit: reported as such
    if run.thrust_n is not None:
        res.thrust_note = THRUSTS_GIVEN
        return
    sens_t, sens = run.input_sensitivity(table, clamp=clamp)
    if sens is None or sens.empty:
        res.thrust_note = NO_UNCERTAINTY
        return
    c = batch_consider(res, sens_t, sens, sigma_pos_m=sigma_pos_m, sigma_yaw_rad=sigma_yaw_rad)
    res.add_thrust_covariance(c.cov_thrust, c.names)
    res.thrust_note = ("sigma = measurement noise + the modules' thrust table uncertainty "
                       f"({', '.join(c.names)})")


def structure_keys(res: BatchResult, run: Run) -> dict[str, Any]:
    """The structure keys of ``estimate batch --json``: the centre of mass ``com_x_m``,
    ``com_y_m`` (m, tracked frame) with sigmas, and ``izz_origin_kgm2`` = Izz about the
    tracked origin ``izz + m (cx^2 + cy^2)`` (kg m^2) with its sigma from the covariance
    (first order); truth errors on a simulated run. Sigma 0 for a fixed value."""
    return com_keys(res.params, res.names, res.cov, run)


def com_keys(values: Mapping[str, float], names: Sequence[str], cov: np.ndarray,
             run: Run) -> dict[str, Any]:
    """The keys of :func:`structure_keys` from any estimate (a vehicle run's also
    ``vehicle``: its name, beside ``structure``): ``values`` every parameter's
    value (mass, izz, cx, cy; estimated or fixed), ``names`` the estimated ones and ``cov``
    the covariance of the state ``(x, y, psi, u, v, r, *names)`` (a batch fit's, or a
    filter's final P). Sigma 0 for a fixed value."""
    m, izz, cx, cy = (float(values[k]) for k in ("mass", "izz", "cx", "cy"))
    idx = {n: 6 + i for i, n in enumerate(names)}
    cov = np.asarray(cov, float)
    sig = {n: float(math.sqrt(max(cov[idx[n], idx[n]], 0.0))) if n in idx else 0.0
           for n in ("cx", "cy")}
    grad = {"mass": cx * cx + cy * cy, "izz": 1.0, "cx": 2 * m * cx, "cy": 2 * m * cy}
    g = np.zeros(len(cov))
    for n, v in grad.items():
        if n in idx:
            g[idx[n]] = v
    out: dict[str, Any] = {
        "structure": run.structure.name,
        **({"vehicle": run.structure.name} if run.structure.kind == "vehicle" else {}),
        "com_x_m": cx, "com_x_sigma_m": sig["cx"], "com_y_m": cy, "com_y_sigma_m": sig["cy"],
        "izz_origin_kgm2": izz + m * (cx * cx + cy * cy),
        "izz_origin_sigma_kgm2": float(math.sqrt(max(float(g @ cov @ g), 0.0)))}
    truth = run.truth or {}
    if "mass_kg" in truth:
        tcx, tcy = float(truth.get("cx", 0.0)), float(truth.get("cy", 0.0))
        out.update({"truth_com_x_m": tcx, "truth_com_y_m": tcy,
                    "com_x_error_m": cx - tcx, "com_y_error_m": cy - tcy})
    return out
