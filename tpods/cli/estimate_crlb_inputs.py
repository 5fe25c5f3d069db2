"""``tpods estimate crlb RUN --vehicle V --estimate mass,izz,...,delay,drop [--at ...]``:
the joint Cramér-Rao bound of a vehicle's body and valve parameters
(:func:`estimator.estimate.vehicle_bound.bound_with_inputs`), printed, as ``--json`` or
written to crlb.json. :mod:`tpods.cli.estimate_batch` dispatches here when ``--estimate``
names delay or drop."""

from __future__ import annotations

import argparse
import math
import sys

from common.errors import UserError
from tpods.cli.estimate_output import print_json, write_json

_UNITS = {"mass": "kg", "izz": "kg m^2", "cx": "m", "cy": "m", "delay": "s",
          "drop": "per other open valve"}


def _unit(name: str) -> str:
    from estimator.plant.parameter_sets import PARAM_UNITS

    return _UNITS.get("drop" if name.startswith("drop.") else name, PARAM_UNITS.get(name, ""))


def cmd_crlb_inputs(args: argparse.Namespace, out_folder) -> int:
    """The joint bound of ``args.estimate`` (plant names and delay/drop) on a recorded
    vehicle run; a not-informed parameter is one warning line (stderr) and ``null`` in the
    JSON's ``crlb_sigma`` with its reason in ``not_informed``."""
    from estimator.batch.input_params import split_names
    from estimator.estimate import BoundOptions
    from estimator.estimate.vehicle_bound import bound_with_inputs

    if args.model not in (None, "ideal"):
        raise UserError("--estimate with delay/drop bounds the ideal model's parameters (name "
                        "friction ones in --estimate instead of --model)")
    o = BoundOptions(window=args.window, mass_kg=args.mass, izz_kgm2=args.izz,
                     sigma_pos_m=args.sigma_pos, sigma_yaw_rad=math.radians(args.sigma_yaw_deg))
    b = bound_with_inputs(args.run_dir, args.thrust_table, o, *split_names(args.estimate),
                          structure=args.structure, at=args.at)
    out = b.to_dict()
    for w in out["warnings"]:
        print(f"tpods: warning: {w}", file=sys.stderr)
    if not out["thrust_uncertainty"]["included"]:
        print(f"tpods: warning: {out['thrust_uncertainty']['note']}", file=sys.stderr)
    if out_folder is not None:
        with out_folder.writing_main() as (main, _):
            write_json(main, out)
    if args.json:
        print_json(out)
        return 0
    print(f"Cramér-Rao bound of {args.run_dir} (recorded, {out['n_poses']} poses over "
          f"{out['duration_s']:.1f} s; plant from {b.plant_source}), jointly with the valves")
    for n, s in out["crlb_sigma"].items():
        at = f"at {out['at'][n]:.6g} {_unit(n)}"
        if s is None:
            print(f"  {n:<5} not informed by this run ({out['not_informed'][n]}); {at}")
        else:
            total = out.get("crlb_sigma_total", {}).get(n)
            with_f = f" (with the stated forces {total:.4g})" if total is not None else ""
            print(f"  {n:<5} sigma >= {s:.4g} {_unit(n)}{with_f}, {at}")
    if out["crlb_corr_mass_izz"] is not None:
        print(f"  correlation(mass, Izz) {out['crlb_corr_mass_izz']:+.3f}, "
              f"log det(information) {out['logdet_info']:.3f}")
    if out_folder is not None:
        print(f"  wrote {out_folder.main}")
    return 0
