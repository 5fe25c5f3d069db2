"""What ``tpods run play`` and ``tpods run plant`` add for a vehicle: which
layout ``--structure``/``--vehicle`` gave (:func:`split_layout`) and a vehicle's default
``--duty-limits`` (:func:`vehicle_duty_limits`). The commands themselves are
:mod:`tpods.cli.run`; the vehicle's plant is :mod:`tpods.plant_vehicle`."""

from __future__ import annotations

import argparse
from typing import Any

from tpods.cli.options import DEFAULT_DUTY_LIMITS  # noqa: F401  (re-exported: run.py)


def split_layout(args: argparse.Namespace) -> tuple[Any, Any]:
    """``(structure, vehicle)`` of ``args.structure`` (``--structure F`` or ``--vehicle
    FILE``): the one the file holds, the other None (both None without a file). A
    structure with a vehicle module is refused in one line
    (:func:`common.layout_files.load_live_layout`)."""
    if not args.structure:
        return None, None
    from common.layout_files import load_live_layout

    layout = load_live_layout(args.structure)
    return (None, layout) if layout.kind == "vehicle" else (layout, None)


def vehicle_duty_limits(vehicle) -> str:
    """A vehicle's ``--duty-limits LOW,HIGH`` default: the open duties its thrusters accept
    (:meth:`common.layout.ThrusterLayout.duty_range`; on/off valves only: ``1,100``, an
    on/off valve is opened with 100)."""
    lo, hi = vehicle.duty_range()
    return f"{max(lo, 1.0):g},{hi:g}"
