"""``tpods calibrate bifilar|trifilar``: Izz from a pendulum's swing (thin shell).

Sources: stopwatch timings (--times), a mocap yaw trace (--poses), a gyro's yaw rate
(--rates) or any signal proportional to the angle (--trace: pixels, a laser spot,
encoder counts). The use case is :mod:`calibration.swing.measure`, its text report
:mod:`calibration.swing.summary`.
"""

from __future__ import annotations

import argparse
import json
import math
import sys

from common.argtypes import float_list, int_at_least, nonneg_float, positive_float, time_window
from common.constants import G_STANDARD_MPS2
from tpods.cli.options import add_result_out

NEW_INPUTS = (
    "--rates: a gyro's yaw-rate log (CSV: time, rate; --columns, --time-unit, --rate-unit); "
    "the derivative of the large-angle model is fitted with the gyro's bias and drift. "
    "--trace: any signal proportional to the swing angle (pixels, a laser spot, encoder counts; "
    "CSV: time, value, or --sample-rate for a video track); the period is scale-free, the "
    "amplitude correction needs --trace-scale, else its possible size is in the sigma. Every "
    "trace fit bounds the damping at zero, models a second mode (the sway at sqrt(g/L)) when it "
    "is there, and falls back to the period method with a wider sigma when its residual is "
    "more than 3 times the sensor noise (docs/calibration.md).")


def register_bifilar(cal) -> None:
    """``tpods calibrate bifilar`` (its help text as before, the new inputs added)."""
    p = cal.add_parser(
        "bifilar", help="Izz from a bifilar pendulum: stopwatch timings (Eq. 19) or a mocap trace",
        description="Izz of a body hung from two parallel strings. --times: the paper's Eq. 19, "
                    "Izz = m g D^2 T^2 / (16 pi^2 h), on the mean period, with an uncertainty "
                    "budget per input. --poses: fit the nonlinear large-angle model with viscous "
                    "and quadratic damping to the recorded yaw; Eq. 19 on the trace's period and "
                    "the amplitude correction are reported beside it.", epilog=NEW_INPUTS)
    _pendulum_options(p, "body mass, kg",
                      ("--spacing", "D_M", "horizontal separation D of the strings, m"),
                      ("H_M", "unsupported vertical length h of the strings, m"), "kind_bifilar")


def register_trifilar(cal) -> None:
    """``tpods calibrate trifilar``: three strings at radius R, the same inputs and output."""
    p = cal.add_parser(
        "trifilar", help="Izz from a trifilar pendulum: timings, a mocap, gyro or camera trace",
        description="Izz of a body on a platform hung from three parallel strings of length L "
                    "at radius R from its centre (the centre of mass on the axis). --times: "
                    "I = m g R^2 T^2 / (4 pi^2 L) on the mean period, with an uncertainty budget "
                    "per input (R, L, m, T, g). --poses, --rates, --trace: the large-angle model "
                    "(the trifilar lifts its body as a bifilar of spacing 2R does) fitted as for "
                    "'tpods calibrate bifilar'.", epilog=NEW_INPUTS)
    _pendulum_options(p, "mass of everything that swings (platform and body), kg",
                      ("--radius", "R_M", "radius R of the string attachments from the centre, m"),
                      ("L_M", "vertical length L of the strings, m"), "kind_trifilar")


def _pendulum_options(p, mass_help: str, size: tuple[str, str, str], length: tuple[str, str],
                      kind: str) -> None:
    """A pendulum's options in their --help order: --mass, its size (``size``: the option,
    metavar and help of --spacing D or --radius R), --length (``length``: metavar, help), the
    sources, the size's uncertainty (--u-spacing or --u-radius), then the rest."""
    opt, metavar, size_help = size
    p.add_argument("--mass", type=positive_float, required=True, metavar="KG", help=mass_help)
    p.add_argument(opt, type=positive_float, required=True, metavar=metavar, help=size_help)
    p.add_argument("--length", type=positive_float, required=True, metavar=length[0],
                   help=length[1])
    src = _sources(p)
    p.add_argument(f"--u-{opt[2:]}", type=nonneg_float, default=1e-3, metavar="M",
                   help=f"standard uncertainty of {metavar[0]}, m (default 0.001)")
    _rest(p, src, kind)


def _sources(p):
    """The four sources (one required), then --cycles and --u-mass."""
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--times", type=float_list(), metavar="T1,T2,...",
                     help="stopwatch time of --cycles full oscillations per trial, s")
    src.add_argument("--poses", metavar="PATH",
                     help="poses.csv (t,x,y,psi) recorded while the body swings, or its run folder")
    src.add_argument("--rates", metavar="FILE",
                     help="a gyro's yaw-rate log: CSV time and rate (rad/s, s by default)")
    src.add_argument("--trace", metavar="FILE",
                     help="CSV time and any value proportional to the swing angle (pixels, counts)")
    p.add_argument("--cycles", type=int_at_least(1), default=10,
                   help="full oscillations per timing (default 10)")
    p.add_argument("--u-mass", type=nonneg_float, default=2.5e-3 / math.sqrt(3), metavar="KG",
                   help="standard uncertainty of m, kg (default 1.44e-3: +-2.5 g rectangular)")
    return src


def _rest(p, src, kind: str) -> None:
    p.add_argument("--u-length", type=nonneg_float, default=2e-3, metavar="M",
                   help=f"standard uncertainty of {'h' if kind == 'kind_bifilar' else 'L'}, m "
                        "(default 0.002)")
    p.add_argument("--u-timing", type=nonneg_float, default=0.0, metavar="S",
                   help="extra per-timing stopwatch error, s (default 0: the spread covers it)")
    p.add_argument("--tare-izz", type=nonneg_float, default=0.0, metavar="KGM2",
                   help="inertia of a fixture to subtract, kg m^2")
    p.add_argument("--u-tare", type=nonneg_float, default=0.0, metavar="KGM2",
                   help="standard uncertainty of --tare-izz")
    p.add_argument("--g", type=positive_float, default=G_STANDARD_MPS2,
                   help=f"m/s^2 (default {G_STANDARD_MPS2})")
    p.add_argument("--u-g", type=nonneg_float, default=0.0, help="uncertainty of g (default 0)")
    p.add_argument("--window", type=time_window, default=None, metavar="T0:T1",
                   help="use only poses with T0 <= t <= T1, s (--poses); T0,T1 is read too")
    p.add_argument("--no-rise-ke", action="store_true",
                   help="omit the kinetic energy of the body's rise (Jardin & Mueller's form)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    add_result_out(p, "result.json and plots", "result")
    log = p.add_argument_group("--rates and --trace logs")
    log.add_argument("--columns", default=None, metavar="SPEC",
                     help="t=COL,rate=COL (--rates) or t=COL,value=COL (--trace): the columns by "
                          "header name or 1-based number (default: the t/time column or the "
                          "first; the rate/value column or the next)")
    log.add_argument("--time-unit", choices=("s", "ms", "us"), default="s", metavar="UNIT",
                     help="unit of the time column: s (default), ms or us")
    log.add_argument("--rate-unit", choices=("rad/s", "deg/s", "rpm"), default="rad/s", metavar="UNIT",
                     help="unit of the --rates column: rad/s (default), deg/s or rpm")
    log.add_argument("--sample-rate", type=positive_float, default=None, metavar="HZ",
                     help="the log has no time column: sample n is at n/HZ s (a video track)")
    log.add_argument("--trace-scale", type=float, default=None, metavar="K",
                     help="--trace: the angle per unit of the signal, RAD_PER_UNIT; fits the "
                          "large-angle model (else the period only, the amplitude correction in "
                          "the sigma)")
    log.add_argument("--amplitude-max", type=positive_float, default=15.0, metavar="DEG",
                     help="--trace without --trace-scale: the largest swing the sigma allows for "
                          "(default 15 deg)")
    p.set_defaults(func=cmd_pendulum, suspension=kind.split("_")[1])


def cmd_pendulum(args: argparse.Namespace) -> int:
    from calibration.suspension import Suspension
    from calibration.swing.measure import measure_izz
    from calibration.swing.summary import summary_lines

    tri = args.suspension == "trifilar"
    s = Suspension(args.suspension, args.mass, args.radius if tri else args.spacing, args.length,
                   u_mass_kg=args.u_mass, u_arm_m=args.u_radius if tri else args.u_spacing,
                   u_length_m=args.u_length, g=args.g, u_g=args.u_g, tare_izz_kgm2=args.tare_izz,
                   u_tare_kgm2=args.u_tare)
    m = measure_izz(s, times=args.times, cycles=args.cycles, poses=args.poses, rates=args.rates,
                    trace=args.trace, u_timing=args.u_timing, window=args.window,
                    rise_ke=not args.no_rise_ke, columns=args.columns, time_unit=args.time_unit,
                    rate_unit=args.rate_unit, sample_rate=args.sample_rate,
                    trace_scale=args.trace_scale, amplitude_max=args.amplitude_max, out=args.out,
                    force=args.force, on_warning=lambda w: print(f"tpods: warning: {w}", file=sys.stderr))
    if args.json:
        json.dump(m.doc, sys.stdout, indent=2, default=float)
        sys.stdout.write("\n")
        return 0
    lines, notes = summary_lines(m.result, m.source)
    for n in notes:
        print(n, file=sys.stderr)
    for line in lines:
        print(line)
    for f in m.files:
        print(f"wrote {f}")
    return 0
