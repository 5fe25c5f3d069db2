"""``tpods estimate crlb RUN --vehicle V --estimate mass,izz,cx,cy,delay,drop``:
the Cramér-Rao bound of the joint parameter set that ``estimate batch`` fits with a
vehicle's valve dead time and supply drop, from the same information matrix
(:func:`estimator.batch.input_params.crlb_input_params`: the batch fit's Jacobian).

The point the bound is evaluated at: ``at`` (any of mass, izz, cx, cy, delay, drop), else
the run's truth (run.json), else the vehicle's [body] and the run's own valve values
(:func:`estimator.estimate.vehicle_inputs.truth_inputs`); ``mass_kg``/``izz_kgm2`` of the
options win over the truth. A parameter the run does not inform (no two valves of a supply
ever open together, valves that never open, a bound above the batch fit's
:data:`~estimator.batch.input_params.UNINFORMED_SIGMA` or an infinite one) is not bounded:
it is held at its value, as the batch fit holds it, and reported in ``not_informed`` with
the reason (never a NaN or an infinity in the result). Beside the noise bound: the
vehicle's stated force uncertainty considered at the same point
(:mod:`estimator.batch.input_consider`), ``crlb_sigma_thrust`` and ``crlb_sigma_total``."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from common.errors import UserError
from common.runfolder import read_run
from estimator.batch.crlb import CRLBResult, safe_inverse
from estimator.batch.input_params import (
    UNINFORMED_SIGMA,
    InputModel,
    crlb_input_params,
    is_input_name,
)
from estimator.estimate.bound import Bound
from estimator.estimate.options import BoundOptions, _windowed, as_window
from estimator.estimate.vehicle_inputs import BODY_NAMES, truth_inputs, valve_vehicle

NO_FORCE_SIGMA_NOTE = ("the vehicle states no force uncertainty (force_sigma_n, a table's, "
                       "drop_sigma) that reaches these commands: the bound covers measurement "
                       "noise only")
AT_NAMES = ("mass", "izz", "cx", "cy", "delay", "drop")
"""The names ``at`` takes (``drop`` sets every on/off supply's)."""


def check_at(at, vehicle) -> None:
    """``--at`` through the same ranges as vehicle.toml (:mod:`common.plausible_inputs`):
    a zero mass is refused, not taken as "not given"."""
    from common.plausible_inputs import check_drop, check_positive, check_time_s

    for k in ("mass", "izz"):
        if k in at:
            check_positive(at[k], f"--at {k}")
    if "delay" in at:
        check_time_s(at["delay"], "--at delay")
    if "drop" in at:
        for supply, idx in vehicle.onoff_supplies().items():
            check_drop(at["drop"], len(idx), f"--at drop (supply {supply})")


def _point(run, v, o: BoundOptions, at: Mapping[str, float]) -> tuple[dict, Any, str]:
    """``(plant params, vehicle at the input values, source of the plant)``."""
    bad = [k for k in at if k not in AT_NAMES]
    if bad:
        raise UserError(f"--at: unknown name {bad[0]!r}; use {', '.join(AT_NAMES)}")
    truth, body = run.truth or {}, v.body
    check_at(at, v)
    mass = at.get("mass") or o.mass_kg or truth.get("mass_kg") or body.mass_kg
    izz = at.get("izz") or o.izz_kgm2 or truth.get("izz_kgm2") or body.izz_kgm2
    if mass is None or izz is None:
        raise UserError(f"{run.path}: no mass or Izz to bound at (no run.json truth, no [body] "
                        "mass_kg/izz_kgm2 in the vehicle): give --mass and --izz")
    source = ("command line" if ({"mass", "izz"} & set(at) or o.mass_kg or o.izz_kgm2) else
              "run truth" if "mass_kg" in truth else "vehicle [body]")
    com = (truth["cx"], truth.get("cy", 0.0)) if "cx" in truth else (body.com_m or (0.0, 0.0))
    params = {"mass": float(mass), "izz": float(izz), "cx": float(at.get("cx", com[0])),
              "cy": float(at.get("cy", com[1])),
              **{k: float(truth.get(k, 0.0)) for k in ("ct", "cr", "kb", "ax", "ay")}}
    tv = truth_inputs(run, v)
    drops = {s: float(at["drop"]) for s in tv.onoff_supplies()} if "drop" in at else None
    return params, tv.with_input_params(at.get("delay"), drops), source


def _loose(c: CRLBResult, inputs: Sequence[str]) -> dict[str, str]:
    """``{name: why}`` of the bound's parameters the run informs too little."""
    out = {}
    for n, s in zip(c.names, c.sigma, strict=True):
        limit = UNINFORMED_SIGMA["delay" if n == "delay" else "drop"] if n in inputs else None
        if not np.isfinite(s):
            out[n] = "the run holds no information on it (infinite bound)"
        elif limit is not None and s > limit:
            out[n] = f"too little information (bound {s:.3g} > {limit:g})"
    return out


def bound_with_inputs(path: str | Path, table, o: BoundOptions, plant: Sequence[str],
                      inputs: Sequence[str], *, structure: Any = None,
                      at: Mapping[str, float] | None = None) -> Bound:
    """The joint Cramér-Rao bound on ``plant`` (default mass, izz, cx, cy) and the input
    parameters ``inputs`` of a recorded vehicle run (module doc), the initial state a
    nuisance; ``o`` the window, plant and noise of :class:`BoundOptions`."""
    at = dict(at or {})
    p = Path(path)
    if not (p.is_dir() and (p / "poses.csv").exists()):
        raise UserError(f"{p}: the bound on delay and drop needs a recorded run folder (poses.csv)")
    run = read_run(p, structure=structure)
    v, _ = valve_vehicle(run, table)
    wrun = _windowed(run, as_window(o.window))
    params, tv, source = _point(run, v, o, at)
    truth = run.truth or {}
    s0 = truth.get("initial_state") if wrun.pose_t[0] == run.pose_t[0] else None
    s0 = np.asarray(s0 if s0 is not None else [*wrun.pose[0], 0.0, 0.0, 0.0], float)
    plant, inputs = tuple(plant) or BODY_NAMES, tuple(inputs)
    # the same refusals as the batch fit (unknown supply, both drop forms, a table vehicle)
    model = InputModel(tv, wrun.cmd_t, wrun.duty_pct, inputs)
    skipped = model.uninformed()
    while True:
        if set(plant + inputs) <= set(skipped):
            why = "; ".join(f"{n}: {w}" for n, w in skipped.items())
            raise UserError(f"{p}: the run informs none of {', '.join(plant + inputs)} ({why})")
        c = crlb_input_params(wrun.pose_t, tv, wrun.cmd_t, wrun.duty_pct, params,
                              names=tuple(n for n in plant if n not in skipped),
                              input_names=tuple(n for n in inputs if n not in skipped), s0=s0,
                              sigma_pos_m=o.sigma_pos_m, sigma_yaw_rad=o.sigma_yaw_rad)
        loose = _loose(c, inputs)
        if not loose:
            break
        skipped.update(loose)
    values = {**params, **dict(zip(model.names, model.start().tolist(), strict=True))}
    out = _to_dict(c, p, wrun.pose_t, params, source, o, plant + inputs, values, skipped)
    out.update(_budget(c, tv, wrun, s0, values, params, o))
    return Bound("recorded", c, wrun.pose_t, params["mass"], params["izz"], source, out)


def _budget(c: CRLBResult, tv, wrun, s0, values, params, o: BoundOptions) -> dict[str, Any]:
    """The vehicle's stated force uncertainty considered at the bound's point
    (:func:`estimator.batch.input_consider.consider_at` with the inverse Fisher matrix):
    ``crlb_sigma_thrust`` and ``crlb_sigma_total`` (RSS) per bounded parameter."""
    from estimator.batch.input_consider import consider_at

    inputs = tuple(n for n in c.names if is_input_name(n))
    plant = tuple(n for n in c.names if not is_input_name(n))
    z = np.concatenate([s0, [values[n] for n in plant + inputs]])
    cons = consider_at(tv, wrun.pose_t, np.zeros((len(wrun.pose_t), 3)), wrun.cmd_t,
                       wrun.duty_pct, plant, z, params, safe_inverse(c.fisher),
                       input_names=inputs, sigma_pos_m=o.sigma_pos_m,
                       sigma_yaw_rad=o.sigma_yaw_rad)
    if cons is None:
        return {"thrust_uncertainty": {"included": False, "note": NO_FORCE_SIGMA_NOTE}}
    st = np.sqrt(np.maximum(np.diag(cons.cov_thrust)[6:], 0.0))
    return {"thrust_uncertainty": {"included": True, "terms": list(cons.names), "note": ""},
            "crlb_sigma_thrust": dict(zip(c.names, st.tolist(), strict=True)),
            "crlb_sigma_total": dict(zip(c.names, np.hypot(c.sigma, st).tolist(), strict=True))}


def _to_dict(c: CRLBResult, path: Path, pose_t, params, source, o: BoundOptions,
             names: Sequence[str], values: Mapping[str, float],
             skipped: Mapping[str, str]) -> dict[str, Any]:
    """The JSON object of ``tpods estimate crlb --json`` for the joint bound."""
    sigma = {n: (c.sigma_of(n) if n in c.names else None) for n in names}
    sd = np.where(c.sigma > 0, c.sigma, 1.0)
    corr = c.cov / np.outer(sd, sd)
    mi, ii = (c.names.index(n) if n in c.names else None for n in ("mass", "izz"))
    out: dict[str, Any] = {
        "sequence": "recorded", "path": str(path), "n_poses": c.n_poses,
        "duration_s": float(pose_t[-1] - pose_t[0]), "mass_kg": params["mass"],
        "izz_kgm2": params["izz"], "plant_source": source,
        "crlb_mass_sigma_kg": sigma.get("mass"), "crlb_izz_sigma_kgm2": sigma.get("izz"),
        "crlb_corr_mass_izz": (float(corr[mi, ii]) if mi is not None and ii is not None
                               else None),
        "logdet_info": c.logdet, "sigma_pos_m": o.sigma_pos_m,
        "sigma_yaw_rad": o.sigma_yaw_rad, "model": "custom", "estimated": list(c.names),
        "crlb_sigma": sigma,
        "at": {n: float(values[n]) for n in names},
        "not_informed": dict(skipped),
        "warnings": [f"{n} is not bounded: {why}; held at {values[n]:g}"
                     for n, why in skipped.items()],
        "crlb_correlation": corr.tolist()}
    return out
