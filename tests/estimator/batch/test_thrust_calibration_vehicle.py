"""In-situ calibration of a structure (the interface a vehicle file implements: n_channels,
thrust_n, module_wrench_matrix, virtual_sensitivity): eight thrusters' efficiencies and Izz
with only the mass known, within 3 sigma; a dead thruster of module 2 named by its column;
nozzle-count factors refused for a vehicle."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from common.errors import UserError
from common.structure import Body, Module, Structure
from common.thrust_table import ThrustTable
from common.thrust_uncertainty import ThrustUncertainty
from estimator.batch.thrust_calibration.calibrate import calibrate_thrust
from estimator.batch.thrust_calibration.vehicle import VehicleThrust
from estimator.plant.inputs import make_input
from estimator.plant.model import PlantParams
from estimator.plant.sim import SimConfig, simulate

PAIR = Structure("pair", (Module("tpods1", (-0.22, 0.0), 0.0),
                          Module("tpods2", (0.22, 0.04), 90.0)), Body())
TRUTH = PlantParams(1.7, 0.032)


def _random_valves(duration_s=40.0, step_s=0.5, n=8, duty_pct=30.0, seed=0):
    """On/off valves in random combinations (every thruster's force and torque apart)."""
    rng = np.random.default_rng(seed)
    cmd_t = np.arange(0.0, duration_s + 1e-9, step_s)
    duty = np.where(rng.random((len(cmd_t), n)) < 0.35, duty_pct, 0.0)
    duty[-1] = 0.0
    return cmd_t, duty


def _sim(gains, seed=1, structure=PAIR):
    cmd_t, duty = _random_valves(n=structure.n_channels)
    v = VehicleThrust(structure, duty, 0.05)
    thrust = (v.phys * np.asarray(gains)) @ v.V.T
    return simulate(cmd_t, duty, TRUTH, thrust_n=thrust, config=SimConfig(seed=seed)), cmd_t, duty


def test_virtual_thrust_matches_the_structure():
    cmd_t, duty = make_input("phase-sine", 5.0, 50.0, 20.0, 1.0, n_channels=8)
    v = VehicleThrust(PAIR, duty, PAIR.arm_m)
    assert np.allclose(v.factor_thrust((), ())[0], PAIR.virtual_thrust(duty), atol=1e-12)


@pytest.mark.parametrize("per", ["thruster", "common"])
def test_structure_factors_and_izz_within_3_sigma(per):
    gains = np.array([1.0, 0.95, 1.0, 1.02, 0.98, 1.0, 1.0, 1.03]) if per == "thruster" else np.full(8, 0.97)
    s, cmd_t, duty = _sim(gains)
    r = calibrate_thrust(s.pose_t, s.pose, cmd_t, duty, PAIR, mass_kg=TRUTH.mass_kg, izz_kgm2=None,
                         mass_sigma_kg=0.005, per=per)
    want = gains if per == "thruster" else gains[:1]
    assert r.converged and len(r.names) == len(want)
    assert np.all(np.abs(r.values - want) < 3 * r.sigma), (r.values, r.sigma)
    assert abs(r.izz["izz_kgm2"] - TRUTH.izz_kgm2) < 3 * r.izz["izz_sigma_kgm2"]
    assert not r.warnings, r.warnings


def test_dead_thruster_of_module_two_named():
    gains = np.ones(8)
    gains[5] = 0.0
    s, cmd_t, duty = _sim(gains, seed=2)
    r = calibrate_thrust(s.pose_t, s.pose, cmd_t, duty, PAIR, mass_kg=TRUTH.mass_kg, izz_kgm2=None)
    dead = [w for w in r.warnings if "Dead or blocked" in w]
    assert len(dead) == 1 and dead[0].startswith("thruster 6 (column d6)"), r.warnings


def test_stated_uncertainty_carried_and_nozzle_factors_refused():
    t = replace(ThrustTable.default(), uncertainty=ThrustUncertainty(0.02))
    pair = Structure("pair", tuple(replace(m, table=t) for m in PAIR.modules), Body())
    s, cmd_t, duty = _sim(np.ones(8), structure=pair)
    r = calibrate_thrust(s.pose_t, s.pose, cmd_t, duty, pair, mass_kg=TRUTH.mass_kg,
                         izz_kgm2=TRUTH.izz_kgm2, per="common")
    # a common scale absorbs neither module's own scale alone
    assert set(r.table_terms) == {"tpods1:scale", "tpods2:scale"} and np.all(np.diag(r.cov_table) > 0)
    r = calibrate_thrust(s.pose_t, s.pose, cmd_t, duty, pair, mass_kg=TRUTH.mass_kg,
                         izz_kgm2=TRUTH.izz_kgm2, per="thruster")
    assert r.absorbed == ("tpods1:scale", "tpods2:scale") and not r.table_terms
    with pytest.raises(UserError, match="nozzle-count factors belong to a thrust table"):
        calibrate_thrust(s.pose_t, s.pose, cmd_t, duty, pair, mass_kg=1.7, izz_kgm2=0.032,
                         per="nozzles")
