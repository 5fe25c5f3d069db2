"""Mass and Izz of a structure built from parts (parallel-axis theorem).

Each part: mass m_i (kg), Izz_i about its own centre of mass (kg m^2) and the
position r_i = (x_i, y_i) (m) of that centre in the plane. About a point O:

    M = sum m_i,   c = sum m_i r_i / M,   Izz_O = sum (Izz_i + m_i |r_i - O|^2)

and about the composite centre Izz_c = Izz_O - M |c - O|^2. Uncertainties of the
parts (uncorrelated) propagate to first order; about c the shift of c itself drops
out of the derivatives because sum m_i (r_i - c) = 0.

PARTS.toml (see calibration/examples/truss_two_modules.toml):

    about = "com"            # or [x, y] in metres: the point Izz is reported about
    [[part]]
    name = "module A"
    mass_kg = 0.720
    izz_kgm2 = 1.2e-3        # or shape = "rod" (length_m), "box" (size_m = [a, b]),
                             #    "disk" (radius_m), "point"
    position_m = [-0.35, 0.0]
    mass_sigma_kg = 1.4e-3   # optional uncertainties
    izz_sigma_kgm2 = 2e-5
    position_sigma_m = 0.002

A top-level ``pendulum_check = "check.json"`` (a ``tpods calibrate pendulum-check --json``
or ``--out`` result, relative to PARTS.toml) names the test-mass check of the pendulum whose
swings gave the parts' ``izz_kgm2``; a part's own ``pendulum_check`` overrides it. The
result then carries each check's verdict (``pendulum_checks``), and a failed check is a
warning naming the parts it concerns.
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from common.errors import UserError
from common.plausible import BODY_MASS_RANGE_KG, body_problems, gyration_problem
from common.tomlfile import read_toml, toml_number


@dataclass(frozen=True)
class Part:
    """One rigid part; SI units, Izz about its own centre of mass."""

    name: str
    mass_kg: float
    izz_kgm2: float
    x_m: float
    y_m: float
    mass_sigma_kg: float = 0.0
    izz_sigma_kgm2: float = 0.0
    position_sigma_m: float = 0.0
    pendulum_check: dict[str, Any] | None = None
    """The summary of the test-mass check of the pendulum that gave ``izz_kgm2``, if named."""


@dataclass
class Composite:
    """Mass, centre of mass and Izz (about ``about_m`` and about the centre)."""

    mass_kg: float
    mass_sigma_kg: float
    com_m: tuple[float, float]
    about_m: tuple[float, float]
    izz_kgm2: float
    izz_sigma_kgm2: float
    izz_com_kgm2: float
    izz_com_sigma_kgm2: float
    parts: list[dict[str, Any]] = field(default_factory=list)
    com_sigma_m: tuple[float, float] = (0.0, 0.0)
    pendulum_checks: list[dict[str, Any]] = field(default_factory=list)
    """Each named pendulum check's summary with the ``parts`` whose Izz it concerns."""

    def to_dict(self) -> dict[str, Any]:
        d = dict(self.__dict__)
        if not d["pendulum_checks"]:
            del d["pendulum_checks"]
        return d


def compare(gt: Composite, est: dict[str, Any]) -> list[dict[str, Any]]:
    """The ground truth from parts against an estimate's JSON object (``tpods estimate batch
    --json`` or its estimate.json): one row per quantity both hold (mass, Izz about the centre
    of mass, the centre of mass's x and y in the tracked frame): values, sigmas, the
    difference and the difference in combined sigmas ``sqrt(s_gt^2 + s_est^2)``."""
    rows = []
    pairs = [("mass", "kg", gt.mass_kg, gt.mass_sigma_kg, "mass_kg", "mass_sigma_kg"),
             ("Izz (centre of mass)", "kg m^2", gt.izz_com_kgm2, gt.izz_com_sigma_kgm2,
              "izz_kgm2", "izz_sigma_kgm2"),
             ("centre of mass x", "m", gt.com_m[0], gt.com_sigma_m[0], "com_x_m", "com_x_sigma_m"),
             ("centre of mass y", "m", gt.com_m[1], gt.com_sigma_m[1], "com_y_m", "com_y_sigma_m")]
    for name, unit, g, gs, k, ks in pairs:
        v = est.get(k)
        vs = est.get(ks)
        if not isinstance(v, int | float) or isinstance(v, bool) or not math.isfinite(v):
            continue
        vs = float(vs) if isinstance(vs, int | float) and math.isfinite(vs) else math.nan
        comb = math.hypot(gs, vs) if math.isfinite(vs) else math.nan
        rows.append({"quantity": name, "unit": unit, "ground_truth": g, "ground_truth_sigma": gs,
                     "estimate": float(v), "estimate_sigma": vs, "difference": float(v) - g,
                     "difference_sigmas": (float(v) - g) / comb if comb > 0 else None})
    if not rows:
        raise UserError("the estimate holds none of mass_kg, izz_kgm2, com_x_m, com_y_m")
    return rows


def combine(parts: list[Part], about: str | tuple[float, float] = "com") -> Composite:
    """Combine parts about ``about`` ("com" or a point (x, y), m)."""
    if not parts:
        raise UserError("no parts to combine")
    m = np.array([p.mass_kg for p in parts])
    I = np.array([p.izz_kgm2 for p in parts])
    r = np.array([[p.x_m, p.y_m] for p in parts])
    um = np.array([p.mass_sigma_kg for p in parts])
    uI = np.array([p.izz_sigma_kgm2 for p in parts])
    ur = np.array([p.position_sigma_m for p in parts])
    M = float(m.sum())
    c = (m[:, None] * r).sum(0) / M
    o = c if isinstance(about, str) else np.asarray(about, float)
    d2_o = ((r - o) ** 2).sum(1)
    d2_c = ((r - c) ** 2).sum(1)
    izz_o = float((I + m * d2_o).sum())
    izz_c = float((I + m * d2_c).sum())
    # first-order propagation (each part's x and y uncertain by ur independently)
    var_o = (uI**2 + (d2_o * um) ** 2 + ((2 * m * ur) ** 2 * d2_o)).sum()
    var_c = (uI**2 + (d2_c * um) ** 2 + ((2 * m * ur) ** 2 * d2_c)).sum()
    rows = [dict(name=p.name, mass_kg=p.mass_kg, izz_own_kgm2=p.izz_kgm2, position_m=[p.x_m, p.y_m],
                 parallel_axis_kgm2=float(p.mass_kg * d), izz_about_point_kgm2=float(p.izz_kgm2 + p.mass_kg * d))
            for p, d in zip(parts, d2_o, strict=True)]
    # the centre of mass c = sum m r / M: dc/dm_i = (r_i - c) / M, dc/dr_i = m_i / M
    var_com = (((r - c) / M) ** 2 * (um**2)[:, None] + ((m / M) * ur)[:, None] ** 2).sum(0)
    return Composite(M, float(math.sqrt((um**2).sum())), (float(c[0]), float(c[1])),
                     (float(o[0]), float(o[1])), izz_o, float(math.sqrt(var_o)), izz_c,
                     float(math.sqrt(var_c)), rows,
                     (float(math.sqrt(var_com[0])), float(math.sqrt(var_com[1]))),
                     _pendulum_checks(parts))


def _pendulum_checks(parts: list[Part]) -> list[dict[str, Any]]:
    """The parts' pendulum checks, one entry per check file with the parts it concerns."""
    out: dict[str, dict[str, Any]] = {}
    for p in parts:
        if p.pendulum_check is not None:
            entry = out.setdefault(p.pendulum_check["file"], {**p.pendulum_check, "parts": []})
            entry["parts"].append(p.name)
    return list(out.values())


def plausibility_warnings(parts: list[Part], res: Composite) -> list[str]:
    """One line per implausible part (heavier than any air-table body, or more compact than
    a lead sphere of its mass: grams typed as kg?) and for the whole (the rules of
    :mod:`common.plausible`)."""
    out = []
    hi = BODY_MASS_RANGE_KG[1]
    for p in parts:
        what = [f"mass {p.mass_kg:.4g} kg is above {hi:g} kg"] if p.mass_kg > hi else []
        what += [w for w in [gyration_problem(p.mass_kg, p.izz_kgm2, whole_body=False)] if w]
        if what:
            out.append(f"part {p.name!r}: {'; '.join(what)}: mass_kg typed in grams?")
    for chk in res.pendulum_checks:
        if chk["verdict"] != "pass":
            names = ", ".join(repr(n) for n in chk["parts"])
            out.append(f"part(s) {names}: Izz from a pendulum that failed its test-mass check "
                       f"({chk['file']}: {chk['verdict_line']})")
    whole = body_problems(res.mass_kg, res.izz_com_kgm2)
    if whole:
        out.append(f"the composite: {'; '.join(whole)}: implausible for an air-table body; "
                   "check the parts' units (mass_kg in kg, izz_kgm2 in kg m^2, position_m in m)")
    return out


def _num(tab: dict, key: str, where: str, default: float | None = None, positive: bool = False,
         nonneg: bool = True) -> float:
    if key not in tab:
        if default is None:
            raise UserError(f"{where}: missing {key}")
        return default
    return toml_number(tab[key], f"{where}: {key}", positive=positive, nonneg=nonneg)


def _pair(tab: dict, key: str, where: str) -> tuple[float, float]:
    v = tab.get(key)
    if (not isinstance(v, list) or len(v) != 2
            or not all(isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)
                       for x in v)):
        raise UserError(f"{where}: {key} must be [x, y] in metres, got {v!r}")
    return float(v[0]), float(v[1])


def part_izz(tab: dict, mass_kg: float, where: str) -> float:
    """Izz about the part's own centre: given, or from a simple shape."""
    if "izz_kgm2" in tab:
        return _num(tab, "izz_kgm2", where)
    shape = tab.get("shape")
    if shape == "rod":  # thin rod lying in the plane, any orientation
        return mass_kg * _num(tab, "length_m", where, positive=True) ** 2 / 12.0
    if shape == "box":  # a x b footprint, rotating about the vertical
        a, b = _pair(tab, "size_m", where)
        if a <= 0 or b <= 0:
            raise UserError(f"{where}: size_m must be positive")
        return mass_kg * (a * a + b * b) / 12.0
    if shape == "disk":
        return mass_kg * _num(tab, "radius_m", where, positive=True) ** 2 / 2.0
    if shape == "point":
        return 0.0
    raise UserError(f"{where}: give izz_kgm2 or shape = rod|box|disk|point (got shape {shape!r})")


PART_KEYS = ("name", "mass_kg", "izz_kgm2", "shape", "length_m", "size_m", "radius_m",
             "position_m", "mass_sigma_kg", "izz_sigma_kgm2", "position_sigma_m", "pendulum_check")
TOP_KEYS = ("about", "part", "pendulum_check")


def _check_keys(tab: dict, valid: tuple[str, ...], where: str) -> None:
    """UserError for a key not in ``valid``, naming the nearest valid key."""
    for key in tab:
        if key not in valid:
            near = difflib.get_close_matches(key, valid, n=1, cutoff=0.5)
            hint = f" (did you mean {near[0]!r}?)" if near else f" (valid: {', '.join(valid)})"
            raise UserError(f"{where}: unknown key {key!r}{hint}")


def load_parts(path: str | Path) -> tuple[list[Part], str | tuple[float, float]]:
    """Read PARTS.toml; returns the parts and the reference point.

    An unknown key (a misspelled ``mass_sigma`` would otherwise be ignored and the
    uncertainty taken as 0) is refused naming the nearest valid key; a UTF-8 BOM is skipped.
    """
    path = Path(path)
    doc = read_toml(path, "parts file")
    raw = doc.get("part")
    if not isinstance(raw, list) or not raw:
        raise UserError(f"{path}: no [[part]] tables")
    _check_keys(doc, TOP_KEYS, str(path))
    checks: dict[str, dict[str, Any]] = {}

    def check(tab: dict, where: str) -> dict[str, Any] | None:
        """The summary of the pendulum check ``tab`` names (read once per file)."""
        from calibration.swing.pendulum_check import load_check_summary

        name = tab.get("pendulum_check")
        if name is None:
            return None
        if not isinstance(name, str) or not name.strip():
            raise UserError(f"{where}: pendulum_check must be the path of a check's JSON, got {name!r}")
        f = str(path.parent / name)
        if f not in checks:
            checks[f] = load_check_summary(f, f"{where}: pendulum_check")
        return checks[f]

    top_check = check(doc, str(path))
    parts = []
    for i, tab in enumerate(raw, start=1):
        name = str(tab.get("name", f"part {i}"))
        where = f"{path}: part {i} ({name})"
        _check_keys(tab, PART_KEYS, where)
        m = _num(tab, "mass_kg", where, positive=True)
        x, y = _pair(tab, "position_m", where)
        own = check(tab, where)
        parts.append(Part(name, m, part_izz(tab, m, where), x, y,
                          _num(tab, "mass_sigma_kg", where, 0.0),
                          _num(tab, "izz_sigma_kgm2", where, 0.0),
                          _num(tab, "position_sigma_m", where, 0.0),
                          own if own is not None else top_check if "izz_kgm2" in tab else None))
    about = doc.get("about", "com")
    if isinstance(about, str):
        if about != "com":
            raise UserError(f"{path}: about must be \"com\" or [x, y], got {about!r}")
    else:
        about = _pair(doc, "about", str(path))
    return parts, about


@dataclass
class CombineReport:
    """The use case's answer: the ``result``, the ``parts`` read, the ``comparison`` rows
    with an estimate (or None) and the plausibility ``warnings``."""

    result: Composite
    parts: list[Part]
    comparison: list[dict[str, Any]] | None
    warnings: list[str]

    def to_dict(self) -> dict[str, Any]:
        return {**self.result.to_dict(),
                **({"comparison": self.comparison} if self.comparison is not None else {})}

    def lines(self, compared_with: str | None = None) -> list[str]:
        """The text report (kg, m, kg m^2), with the comparison against ``compared_with``."""
        res = self.result
        out = [f"mass = {res.mass_kg:.6g} +- {res.mass_sigma_kg:.2g} kg ({len(self.parts)} parts)",
               f"centre of mass = ({res.com_m[0]:.5g}, {res.com_m[1]:.5g}) m",
               f"Izz about ({res.about_m[0]:.5g}, {res.about_m[1]:.5g}) m = {res.izz_kgm2:.6g} +- "
               f"{res.izz_sigma_kgm2:.2g} kg m^2",
               f"Izz about the centre of mass = {res.izz_com_kgm2:.6g} +- {res.izz_com_sigma_kgm2:.2g} kg m^2"]
        out += [f"  {r['name']:32s} m {r['mass_kg']:.4g} kg  Izz own {r['izz_own_kgm2']:.3g}  "
                f"+ m d^2 {r['parallel_axis_kgm2']:.3g} kg m^2" for r in res.parts]
        if self.comparison is not None:
            out.append(f"compared with {compared_with} (difference in combined sigmas):")
            for r in self.comparison:
                z = "-" if r["difference_sigmas"] is None else f"{r['difference_sigmas']:+.1f}"
                out.append(f"  {r['quantity']:22s} parts {r['ground_truth']:.6g} +- "
                           f"{r['ground_truth_sigma']:.2g}   estimate {r['estimate']:.6g} +- "
                           f"{r['estimate_sigma']:.2g} {r['unit']}   difference {r['difference']:+.3g} ({z})")
        return out

    def compare_with(self, path: str | Path) -> list[dict[str, Any]]:
        """Compare with an estimate's JSON file (sets and returns ``comparison``)."""
        import json

        try:
            est = json.loads(Path(path).read_text())
        except FileNotFoundError:
            raise UserError(f"--compare {path}: not found") from None
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            raise UserError(f"--compare {path}: not an estimate's JSON ({exc})") from None
        if not isinstance(est, dict):
            raise UserError(f"--compare {path}: not an estimate's JSON object")
        self.comparison = compare(self.result, est)
        return self.comparison


def combine_file(parts_path: str | Path, about: tuple[float, float] | None = None,
                 compare_with: str | Path | None = None) -> CombineReport:
    """The structure of a PARTS.toml: mass, centre of mass and Izz about ``about`` (m;
    default the file's, else the centre of mass), compared with an estimate's JSON
    (``compare_with``: ``tpods estimate batch --json`` or its estimate.json) if given."""
    parts, file_about = load_parts(parts_path)
    res = combine(parts, file_about if about is None else tuple(about))
    rep = CombineReport(res, parts, None, plausibility_warnings(parts, res))
    if compare_with is not None:
        rep.compare_with(compare_with)
    return rep
