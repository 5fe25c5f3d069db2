"""``tpods calibrate pendulum-check``: the test-mass check of an inertia pendulum (thin shell
over :mod:`calibration.swing.pendulum_series`)."""

from __future__ import annotations

import argparse
import json
import sys

from common.argtypes import nonneg_float, positive_float
from common.constants import G_STANDARD_MPS2
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


def cmd_pendulum_check(args: argparse.Namespace) -> int:
    """Fit I = I0 + m_t r^2 (weighted least squares) to a series of swings with a known test mass
    at known radii and judge the pendulum: the fitted test mass against the known one in sigmas,
    the chi-square of the fit and its p-value. SERIES.csv has one row per swing: radius_m with
    izz_kgm2,izz_sigma_kgm2, or with period_s,period_sigma_s and the pendulum's geometry
    (--string-radius or --spacing, --length, --mass); radius_sigma_m is optional."""

    from calibration.swing.pendulum_series import check_pendulum

    rep = check_pendulum(args.series, args.test_mass_kg, test_mass_sigma_kg=args.test_mass_sigma_kg,
                         string_radius=args.string_radius, spacing=args.spacing,
                         length=args.length, mass=args.mass, u_geometry=args.u_geometry,
                         u_mass=args.u_mass, g=args.g, u_g=args.u_g, out=args.out, force=args.force)
    if rep.check.verdict != "pass":
        for r in rep.check.reasons:
            print(f"tpods: warning: {r}", file=sys.stderr)
    if args.json:
        json.dump(rep.doc, sys.stdout, indent=2, default=float)
        sys.stdout.write("\n")
        return 0
    print("\n".join(rep.lines()))
    for f in rep.files:
        print(f"wrote {f}")
    return 0
