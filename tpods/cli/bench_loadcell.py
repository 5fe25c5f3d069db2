"""``tpods bench import``: load-cell CSV logs as a thrust session (thin shell over
:func:`bench.loadcell_import.import_session`)."""

from __future__ import annotations

import argparse

from common.argtypes import nonneg_float
from common.outputs import add_force
from tpods.cli.parser import command


def register_import(g) -> None:
    """Add ``import`` to the ``bench`` group."""
    p = command(
        g, "import", cmd_import,
        help="a load-cell CSV log (HX711 and the like) as a session bench fit reads")
    p.add_argument("file", metavar="FILE", help="the log (CSV, or tab-separated)")
    p.add_argument("--out", required=True, metavar="SESSION", help="session folder to write")
    p.add_argument("--columns", default=None, metavar="t=COL,force=COL,valves=COL[,phase=COL]",
                   help="the log's column names (default t=t_s,force=weight_g,valves=bitmask,"
                        "phase=phase; the phase column is optional)")
    p.add_argument("--force-unit", default="g", choices=("g", "gf", "kg", "kgf", "N", "mN"),
                   help="unit of the force column; a mass reading (g, kg) is taken as gram- or "
                        "kilogram-force (default g)")
    p.add_argument("--valves-as", default="bitmask", choices=("bitmask", "vector", "duty"),
                   help="bitmask: integer, bit i = valve i+1 open (default); vector: 0/1 per "
                        "valve ('[1, 0, 1, 0]'); duty: percent, one number (valve 1) or one per valve")
    p.add_argument("--time-unit", default="s", choices=("s", "ms"), help="default s")
    p.add_argument("--settle", type=nonneg_float, default=1.0, metavar="S",
                   help="readings after a valve opens left out of its steady force, s (default 1)")
    p.add_argument("--zero-settle", type=nonneg_float, default=1.0, metavar="S",
                   help="readings after the valves close left out of the zero, s (default 1)")
    add_force(p)


def cmd_import(args: argparse.Namespace) -> int:
    """Read a CSV log of another thrust bench (time, force or mass reading, valve state, optional
    phase) into a session folder (raw.csv, steps.csv, run.json) that `tpods bench fit` fits:
    on/off pulses (force per valve and per count, dead time and rise) or duty steps (polynomials
    per nozzle count). Rows are cut where the valve state changes; empty force cells and tare
    phases are skipped and counted."""

    from bench.loadcell_import import import_session

    print("\n".join(import_session(
        args.file, args.out, columns=args.columns, force_unit=args.force_unit,
        valves_as=args.valves_as, time_unit=args.time_unit, settle=args.settle,
        zero_settle=args.zero_settle, force=args.force)))
    return 0
