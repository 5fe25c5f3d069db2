"""``tpods calibrate pendulum-check``: the test-mass check of an inertia pendulum (thin shell
over :mod:`calibration.swing.pendulum_check`)."""

from __future__ import annotations

import argparse
import json
import math
import sys

from common.argtypes import nonneg_float, positive_float
from common.constants import G_STANDARD_MPS2
from common.errors import UserError
from common.outputs import result_output
from tpods.cli.options import add_json_flag, add_result_out
from tpods.cli.parser import command


def register_pendulum_check(cal) -> None:
    """Add ``pendulum-check`` to the ``calibrate`` group."""
    p = command(
        cal, "pendulum-check", cmd_pendulum_check,
        help="the pendulum's own calibration: a known test mass swung at "
             "several radii must add m r^2")
    p.add_argument("series", metavar="SERIES.csv", help="one row per swing (see above)")
    p.add_argument("--test-mass-kg", type=positive_float, required=True, metavar="KG",
                   help="the known test mass, kg")
    p.add_argument("--test-mass-sigma-kg", type=nonneg_float, default=0.0, metavar="KG",
                   help="its standard uncertainty, kg (default 0)")
    geo = p.add_mutually_exclusive_group()
    geo.add_argument("--string-radius", type=positive_float, default=None, metavar="R_M",
                     help="periods: trifilar, the strings' radius from the axis, m")
    geo.add_argument("--spacing", type=positive_float, default=None, metavar="D_M",
                     help="periods: bifilar, the strings' spacing, m")
    p.add_argument("--length", type=positive_float, default=None, metavar="L_M",
                   help="periods: the strings' vertical length, m")
    p.add_argument("--mass", type=positive_float, default=None, metavar="KG",
                   help="periods: the mass on the strings without the test mass, kg")
    p.add_argument("--u-geometry", type=nonneg_float, default=0.0, metavar="M",
                   help="periods: standard uncertainty of the radius (or spacing) and of the "
                        "length, m (default 0)")
    p.add_argument("--u-mass", type=nonneg_float, default=0.0, metavar="KG",
                   help="periods: standard uncertainty of --mass, kg (default 0)")
    p.add_argument("--g", type=positive_float, default=G_STANDARD_MPS2,
                   help=f"m/s^2 (default {G_STANDARD_MPS2})")
    p.add_argument("--u-g", type=nonneg_float, default=0.0, help="uncertainty of g (default 0)")
    add_json_flag(p)
    add_result_out(p, "result.json and check.png", "result")


def _geometry(args: argparse.Namespace):
    from calibration.swing.pendulum_check import PendulumGeometry

    missing = [o for o, v in (("--string-radius or --spacing", args.string_radius or args.spacing),
                              ("--length", args.length), ("--mass", args.mass)) if v is None]
    if missing:
        raise UserError(f"{args.series} gives periods: give the pendulum's {', '.join(missing)}")
    bifilar = args.spacing is not None
    radius = args.spacing / 2 if bifilar else args.string_radius
    return PendulumGeometry(radius, args.length, args.mass,
                            args.u_geometry / 2 if bifilar else args.u_geometry, args.u_geometry,
                            args.u_mass, args.g, args.u_g)


def check_from_args(args: argparse.Namespace):
    """Read SERIES.csv and run the check (periods through the geometry options)."""
    from calibration.swing.pendulum_check import check_series, izz_from_periods, read_series

    cols = read_series(args.series)
    scale_rel = 0.0
    if "period_s" in cols:
        izz, s_izz, scale_rel = izz_from_periods(cols["radius_m"], cols["period_s"],
                                                 cols["period_sigma_s"], _geometry(args),
                                                 args.test_mass_kg, args.test_mass_sigma_kg)
    else:
        given = [o for o, v in (("--string-radius", args.string_radius), ("--spacing", args.spacing),
                                ("--length", args.length), ("--mass", args.mass)) if v is not None]
        if given:
            raise UserError(f"{args.series} gives inertias, not periods: {', '.join(given)} "
                            "would be ignored (they describe the pendulum for periods)")
        izz, s_izz = cols["izz_kgm2"], cols["izz_sigma_kgm2"]
    try:
        return check_series(cols["radius_m"], izz, s_izz, args.test_mass_kg,
                            args.test_mass_sigma_kg, cols.get("radius_sigma_m"), scale_rel)
    except UserError as exc:
        raise UserError(f"{args.series}: {exc}") from None


def cmd_pendulum_check(args: argparse.Namespace) -> int:
    """Fit I = I0 + m_t r^2 (weighted least squares) to a series of swings with a known test mass
    at known radii and judge the pendulum: the fitted test mass against the known one in sigmas,
    the chi-square of the fit and its p-value. SERIES.csv has one row per swing: radius_m with
    izz_kgm2,izz_sigma_kgm2, or with period_s,period_sigma_s and the pendulum's geometry
    (--string-radius or --spacing, --length, --mass); radius_sigma_m is optional."""

    out = result_output(args.out, "result.json", force=args.force,
                        command="tpods calibrate pendulum-check")
    res = check_from_args(args)
    doc = {**res.to_dict(), "series": str(args.series)}
    files = []
    if out is not None:
        from calibration.swing.pendulum_plots import plot_pendulum_check

        with out.writing_main() as (main, d):
            main.write_text(json.dumps(doc, indent=2, default=float) + "\n")
            files.append(main)
            if d is not None:
                files.append(plot_pendulum_check(res, d / "check.png"))
            files = [out.final(f) for f in files]
    if res.verdict != "pass":
        for r in res.reasons:
            print(f"tpods: warning: {r}", file=sys.stderr)
    if args.json:
        json.dump(doc, sys.stdout, indent=2, default=float)
        sys.stdout.write("\n")
        return 0
    n = len(res.radius_m)
    print(f"I0 = {res.i0_kgm2:.6g} +- {res.i0_sigma_kgm2:.2g} kg m^2 (fit of {n} swings, "
          f"r = {min(res.radius_m):.3g}..{max(res.radius_m):.3g} m)")
    print(f"  test mass {res.test_mass_kg * 1e3:.5g} +- {res.test_mass_sigma_kg * 1e3:.2g} g fitted, "
          f"{res.known_test_mass_kg * 1e3:.5g} +- {res.known_test_mass_sigma_kg * 1e3:.2g} g known: "
          f"{res.test_mass_difference_sigmas:+.2f} sigma; scale {res.scale_factor:.4f} +- "
          f"{res.scale_factor_sigma:.2g}")
    dof = res.dof
    print(f"  chi2 = {res.chi2:.3g} for {dof} dof (chi2/dof {res.chi2 / dof if dof else math.nan:.3g}, "
          f"p = {res.p_value:.3g})" + (f"; sigmas scaled by {res.birge_ratio:.3g}"
                                       if res.birge_ratio > 1 else ""))
    print(f"  I0 with the known test mass: {res.i0_known_mass_kgm2:.6g} +- "
          f"{res.i0_known_mass_sigma_kgm2:.2g} kg m^2")
    print(res.verdict_line)
    for f in files:
        print(f"wrote {f}")
    return 0
