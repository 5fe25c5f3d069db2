"""The test-mass check of an inertia pendulum from a SERIES.csv file: the use case behind
``tpods calibrate pendulum-check``, callable from a notebook.

:func:`check_pendulum` reads the series (one row per swing: ``radius_m`` with
``izz_kgm2,izz_sigma_kgm2``, or with ``period_s,period_sigma_s`` and the pendulum's
geometry in m and kg), runs :func:`calibration.swing.pendulum_check.check_series` and,
given ``out``, writes result.json (and check.png in a folder). It returns a
:class:`PendulumSeries` (the check, its JSON, the files written, the text report) and
prints nothing; a user error raises :class:`common.errors.UserError`.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

from calibration.swing.pendulum_check import (
    PendulumCheck,
    PendulumGeometry,
    check_series,
    izz_from_periods,
    read_series,
)
from common.constants import G_STANDARD_MPS2
from common.errors import UserError
from common.outputs import result_output


@dataclass
class PendulumSeries:
    """A checked series: ``check``, ``doc`` (its JSON), ``files`` written."""

    check: PendulumCheck
    doc: dict
    files: list[Path] = field(default_factory=list)

    def lines(self) -> list[str]:
        """The text report: I0, the fitted test mass against the known one, the chi-square,
        the verdict."""
        res = self.check
        n = len(res.radius_m)
        dof = res.dof
        return [f"I0 = {res.i0_kgm2:.6g} +- {res.i0_sigma_kgm2:.2g} kg m^2 (fit of {n} swings, "
                f"r = {min(res.radius_m):.3g}..{max(res.radius_m):.3g} m)",
                f"  test mass {res.test_mass_kg * 1e3:.5g} +- {res.test_mass_sigma_kg * 1e3:.2g} g fitted, "
                f"{res.known_test_mass_kg * 1e3:.5g} +- {res.known_test_mass_sigma_kg * 1e3:.2g} g known: "
                f"{res.test_mass_difference_sigmas:+.2f} sigma; scale {res.scale_factor:.4f} +- "
                f"{res.scale_factor_sigma:.2g}",
                f"  chi2 = {res.chi2:.3g} for {dof} dof (chi2/dof {res.chi2 / dof if dof else math.nan:.3g}, "
                f"p = {res.p_value:.3g})" + (f"; sigmas scaled by {res.birge_ratio:.3g}"
                                             if res.birge_ratio > 1 else ""),
                f"  I0 with the known test mass: {res.i0_known_mass_kgm2:.6g} +- "
                f"{res.i0_known_mass_sigma_kgm2:.2g} kg m^2",
                res.verdict_line]


def check_pendulum(series: str | Path, test_mass_kg: float, *, test_mass_sigma_kg: float = 0.0,
                   string_radius: float | None = None, spacing: float | None = None,
                   length: float | None = None, mass: float | None = None,
                   u_geometry: float = 0.0, u_mass: float = 0.0, g: float = G_STANDARD_MPS2,
                   u_g: float = 0.0, out: str | Path | None = None,
                   force: bool = False) -> PendulumSeries:
    """Fit I = I0 + m_t r^2 to the swings of ``series`` with the known test mass (kg);
    periods need the strings' ``string_radius`` (trifilar) or ``spacing`` (bifilar),
    ``length`` (m) and the ``mass`` on them without the test mass (kg). ``out``: a folder
    (result.json, check.png) or FILE.json, replaced only with ``force``."""
    dest = result_output(None if out is None else str(out), "result.json", force=force,
                         command="tpods calibrate pendulum-check")
    res = _check(series, test_mass_kg, test_mass_sigma_kg, string_radius, spacing, length, mass,
                 u_geometry, u_mass, g, u_g)
    doc = {**res.to_dict(), "series": str(series)}
    files = []
    if dest is not None:
        from calibration.swing.pendulum_plots import plot_pendulum_check  # lazy: matplotlib

        with dest.writing_main() as (main, d):
            main.write_text(json.dumps(doc, indent=2, default=float) + "\n")
            files.append(main)
            if d is not None:
                files.append(plot_pendulum_check(res, d / "check.png"))
            files = [dest.final(f) for f in files]
    return PendulumSeries(res, doc, files)


def _check(series, test_mass_kg, test_mass_sigma_kg, string_radius, spacing, length, mass,
           u_geometry, u_mass, g, u_g) -> PendulumCheck:
    cols = read_series(series)
    scale_rel = 0.0
    if "period_s" in cols:
        missing = [o for o, v in (("--string-radius or --spacing", string_radius or spacing),
                                  ("--length", length), ("--mass", mass)) if v is None]
        if missing:
            raise UserError(f"{series} gives periods: give the pendulum's {', '.join(missing)}")
        bifilar = spacing is not None
        geometry = PendulumGeometry(spacing / 2 if bifilar else string_radius, length, mass,
                                    u_geometry / 2 if bifilar else u_geometry, u_geometry,
                                    u_mass, g, u_g)
        izz, s_izz, scale_rel = izz_from_periods(cols["radius_m"], cols["period_s"],
                                                 cols["period_sigma_s"], geometry,
                                                 test_mass_kg, test_mass_sigma_kg)
    else:
        given = [o for o, v in (("--string-radius", string_radius), ("--spacing", spacing),
                                ("--length", length), ("--mass", mass)) if v is not None]
        if given:
            raise UserError(f"{series} gives inertias, not periods: {', '.join(given)} "
                            "would be ignored (they describe the pendulum for periods)")
        izz, s_izz = cols["izz_kgm2"], cols["izz_sigma_kgm2"]
    try:
        return check_series(cols["radius_m"], izz, s_izz, test_mass_kg, test_mass_sigma_kg,
                            cols.get("radius_sigma_m"), scale_rel)
    except UserError as exc:
        raise UserError(f"{series}: {exc}") from None
