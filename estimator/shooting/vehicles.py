"""The vehicle of a run for the segment fit: the run's own vehicle file, or the TPODS module
(four thrusters of one thrust table with the module's wrench) for a module run."""

from __future__ import annotations

import math

import numpy as np

from common.errors import UserError
from common.layout import module_wrench_1
from common.vehicle import Vehicle
from common.vehicle_toml import Thruster


def module_vehicle(table, arm_m: float | None = None) -> Vehicle:
    """The TPODS module as a vehicle: thruster i with the i-th column of
    :func:`common.layout.module_wrench_1` (direction and moment about the centre)."""
    from common.constants import ARM_M

    arm = ARM_M if arm_m is None else arm_m
    w = module_wrench_1(arm)
    out = []
    for i in range(4):
        dx, dy, mz = w[:, i]
        # a point on the line of action with moment x dy - y dx = mz: mz * (dy, -dx)
        out.append(Thruster(f"T{i + 1}", (float(mz * dy), float(-mz * dx)), (float(dx), float(dy)),
                            table=table))
    v = Vehicle("tpods-module", tuple(out), source="the TPODS module", arm_m=arm)
    assert np.allclose(v.module_wrench_matrix(), w) and math.isfinite(arm)
    return v


def run_vehicle(run, table_path=None) -> Vehicle:
    """The vehicle whose thrusters drive ``run`` (one clear line for a run the segment fit
    does not take)."""
    from common.thrust_table import load_thrust_table

    if run.thrust_n is not None or getattr(run, "wrench_frame", None):
        raise UserError(f"{run.path}: the segment fit takes valve commands (commands.csv) and a "
                        "vehicle, not given thrusts or a wrench")
    v = run.structure
    if v is None:
        if run.duty_pct is None or run.duty_pct.shape[1] != 4:
            raise UserError(f"{run.path}: no vehicle: give --vehicle FILE for a run of "
                            f"{0 if run.duty_pct is None else run.duty_pct.shape[1]} valves")
        return module_vehicle(load_thrust_table(table_path))
    if getattr(v, "kind", None) != "vehicle":
        raise UserError(f"{run.path}: the segment fit takes one vehicle (--vehicle), not a "
                        "structure of modules")
    if table_path is not None:
        v.check_table_option()
        v = v.with_table(load_thrust_table(table_path))
    return v
