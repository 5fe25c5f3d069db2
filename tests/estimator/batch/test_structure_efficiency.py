"""Done-when of issue 18: batch least squares is efficient on simulated structures.

A two-module and a three-module structure (built here, centre of mass 1-5 cm off the
tracked origin, 5 % of the frames dropped) are simulated the way ``tpods sim --structure``
does (the structure's virtual thrusts into the one-module plant), written as structure run
folders and estimated by :func:`estimator.estimate.estimate_run` (what ``tpods estimate
batch`` calls). For mass, Izz, cx and cy: sigma within 10 % of the Cramér-Rao bound at the
truth and the error within 3.5 CRLB sigma.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from common.structure import Body, Module, Structure
from estimator.estimate import estimate_run
from estimator.plant.inputs import make_input
from estimator.plant.model import PlantParams
from estimator.plant.sim import SimConfig, simulate, write_sim_run

TWO = Structure("pair", (Module("tpods1", (-0.22, 0.0), 0.0),
                         Module("tpods2", (0.22, 0.04), 90.0)),
                Body(mass_kg=1.7, izz_kgm2=0.032, com_m=(0.012, -0.008)))
THREE = Structure("tri", (Module("a", (-0.25, 0.0), 0.0), Module("b", (0.25, 0.05), 90.0),
                          Module("c", (0.0, 0.3), 45.0)),
                  Body(mass_kg=2.6, izz_kgm2=0.065, com_m=(0.02, 0.045)))


def simulate_structure(structure: Structure, folder, *, duration_s: float, rate_hz: float,
                       seed: int):
    """A structure run folder as ``tpods sim --structure`` writes it (phase-sine over every
    module's channels, virtual thrusts, 5 % drops)."""
    b = structure.body
    truth = PlantParams(b.mass_kg, b.izz_kgm2, cx=b.com_m[0], cy=b.com_m[1])
    cmd_t, duty = make_input("phase-sine", duration_s, 50.0, 20.0, 1.0,
                             n_channels=structure.n_channels)
    cfg = SimConfig(pose_rate_hz=rate_hz, drop=0.05, seed=seed)
    res = simulate(cmd_t, duty, truth, config=cfg, thrust_n=structure.virtual_thrust(duty))
    write_sim_run(res, folder, "phase-sine")
    structure.write(folder)
    return truth


@pytest.mark.parametrize("structure, rate_hz, seed", [(TWO, 120.0, 11), (THREE, 60.0, 12)],
                         ids=["two-modules", "three-modules"])
def test_batch_is_efficient_on_a_simulated_structure(tmp_path, structure, rate_hz, seed):
    truth = simulate_structure(structure, tmp_path / "run", duration_s=60.0, rate_hz=rate_hz,
                               seed=seed)
    off = math.hypot(truth.cx, truth.cy)
    assert 0.01 <= off <= 0.05
    # the estimator is not told the [body] values: it starts from the modules' layout
    bare = Structure(structure.name, structure.modules, source="test")
    est = estimate_run(tmp_path / "run", structure=bare, estimate=None)
    d = est.to_dict()
    assert d["converged"] and d["estimated"] == ["mass", "izz", "cx", "cy"]
    assert est.crlb is not None and est.crlb.names == ("mass", "izz", "cx", "cy")
    rows = [("mass", d["mass_kg"], d["mass_sigma_kg"], truth.mass_kg),
            ("izz", d["izz_kgm2"], d["izz_sigma_kgm2"], truth.izz_kgm2),
            ("cx", d["com_x_m"], d["com_x_sigma_m"], truth.cx),
            ("cy", d["com_y_m"], d["com_y_sigma_m"], truth.cy)]
    for (name, value, sigma, true), bound in zip(rows, est.crlb.sigma, strict=True):
        assert np.isfinite(bound) and bound > 0
        assert sigma == pytest.approx(bound, rel=0.10), (name, sigma, bound)
        assert abs(value - true) < 3.5 * bound, (name, value, true, bound)
