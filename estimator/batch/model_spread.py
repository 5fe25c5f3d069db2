"""Model uncertainty of a batch fit: how far the mass and Izz move
between the candidate models of ``--model auto`` (ideal, friction, friction+tilt), beside
the sigma of the answer, which covers the pose noise and the stated forces but not the
choice of model.

Which candidates count (:func:`candidate_rows`): a fit that converged and has no
parameter of a sign it cannot have (:mod:`estimator.batch.physical_signs`: damping or a
supply drop below zero by more than 3 sigma). A non-converged fit is no estimate, and a
fit with negative damping has absorbed an unmodelled effect into it. When two counted
fits disagree by more than their combined sigma (:func:`spread`), a warning says the
range; when fewer than two count, the range over every candidate is said with why the
others do not count, if it exceeds the sigma."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from estimator.batch.physical_signs import unphysical

QUANTITIES = (("mass", "mass_kg", "kg", "{:.4g}"), ("Izz", "izz_kgm2", "kg m^2", "{:.4g}"))


def _row(result, model: str) -> dict[str, Any]:
    names = tuple(result.names)
    sig = {n: float(result.sigma[6 + i]) for i, n in enumerate(names)}
    vals = {n: float(result.params.get(n, result.z0[6 + i])) for i, n in enumerate(names)}
    bad = unphysical(names, vals, sig)
    return {"model": model, "mass_kg": float(result.mass_kg),
            "mass_sigma_kg": float(result.mass_sigma_kg), "izz_kgm2": float(result.izz_kgm2),
            "izz_sigma_kgm2": float(result.izz_sigma_kgm2), "converged": bool(result.converged),
            "unphysical": {n: v for n, (v, _) in bad.items()},
            "counts": bool(result.converged) and not bad}


def candidate_rows(fits: Mapping[str, Any], final: Any = None,
                   final_model: str | None = None) -> list[dict[str, Any]]:
    """One row per candidate fit (``fits``: model -> ModelFit); ``final`` (the answer's
    batch result, a refit of ``final_model``) replaces that model's candidate when it
    converged or the candidate did not."""
    rows = []
    for m, f in fits.items():
        r = f.result
        if final is not None and m == final_model and (final.converged or not r.converged):
            r = final
        rows.append(_row(r, m))
    return rows


def _why_not(row: Mapping[str, Any]) -> str:
    if not row["converged"]:
        return "not converged"
    return ", ".join(f"{n} = {v:.3g} < 0" for n, v in row["unphysical"].items())


def spread(rows: list[dict[str, Any]], sigma: Mapping[str, float]) -> tuple[dict[str, Any],
                                                                            list[str]]:
    """``(model_spread, warnings)``: each candidate's values, the range over the counted
    ones (and over all), and a warning per quantity whose range exceeds the sigma.
    ``sigma``: ``mass_kg``/``izz_kgm2`` -> the answer's sigma."""
    counted = [r for r in rows if r["counts"]]
    out: dict[str, Any] = {"models": {r["model"]: r for r in rows},
                           "counted": [r["model"] for r in counted]}
    warnings: list[str] = []
    for label, key, unit, fmt in QUANTITIES:
        skey = key.replace("_kg", "_sigma_kg")
        s = float(sigma.get(key, math.nan))
        pool, all_rows = (counted, False) if len(counted) >= 2 else (rows, True)
        if len(pool) < 2:
            continue
        vals = [r[key] for r in pool]
        lo, hi = min(vals), max(vals)
        worst = max(abs(a[key] - b[key]) / math.hypot(a[skey], b[skey])
                    for i, a in enumerate(pool) for b in pool[i + 1:]
                    if math.hypot(a[skey], b[skey]) > 0) if len(pool) > 1 else 0.0
        out[f"{key}_range"] = [lo, hi]
        out[f"{key}_range_over"] = "all candidates" if all_rows else "counted candidates"
        exceeds = worst > 1.0 and (not math.isfinite(s) or hi - lo > s)
        out[f"{key}_exceeds_sigma"] = bool(exceeds)
        if not exceeds:
            continue
        across = ", ".join(f"{r['model']} {fmt.format(r[key])}" for r in pool)
        line = (f"the {label} depends on the model: {fmt.format(lo)}..{fmt.format(hi)} {unit} "
                f"across {across}, more than its sigma {fmt.format(s)} {unit}: the sigma "
                "covers noise and the stated forces, not the choice of model")
        if all_rows:
            line += ("; and no two candidates are converged fits with physical signs ("
                     + "; ".join(f"{r['model']}: {_why_not(r)}" for r in rows if not r["counts"])
                     + "), so no model here is the answer without doubt")
        warnings.append(line)
    return out, warnings
