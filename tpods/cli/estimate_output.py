"""Text and JSON output shared by the estimate commands (``estimate batch`` with every
method, ``estimate crlb``, ``estimate live``): the uncertainty budget table, a structure's
centre of mass and [body] lines, one JSON object on stdout, a result JSON file.

The command modules (:mod:`tpods.cli.estimate_batch`, :mod:`tpods.cli.estimate_ekf`,
:mod:`tpods.cli.estimate_realism`, :mod:`tpods.cli.estimate_live`) import these; this
module imports none of them.
"""

from __future__ import annotations

import json
import sys
from typing import Any

_UNITS = {"mass": "kg", "izz": "kg m^2", "ct": "N s/m", "cr": "N m s", "kb": "N m s/m",
          "ax": "m/s^2", "ay": "m/s^2", "cx": "m", "cy": "m", "delay": "s", "drop": "per valve"}


def print_json(obj: dict[str, Any]) -> None:
    """``obj`` as exactly one JSON object on stdout (numpy values as numbers)."""
    from common.runwriter import json_default

    sys.stdout.write(json.dumps(obj, default=json_default) + "\n")


def write_json(path, obj: dict[str, Any]) -> None:
    """``obj`` as an indented JSON file at ``path`` (other values as their ``str``)."""
    path.write_text(json.dumps(obj, indent=2, default=str) + "\n")


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
