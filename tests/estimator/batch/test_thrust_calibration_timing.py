"""``tpods calibrate thrust --vehicle V --mass M`` on a vehicle with a valve dead time and
rise (issue 24): the thrusts reach the plant through the vehicle's known valve timing
(VehicleThrust on the timed rows), so the in-flight factors of exact forces come out at 1
within 3.5 sigma; without the timing they would be biased."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from common.vehicle import Vehicle
from estimator.batch.thrust_calibration.calibrate import calibrate_thrust
from estimator.batch.thrust_calibration.vehicle import VehicleThrust
from estimator.plant.inputs import make_input
from estimator.plant.model import PlantParams
from estimator.plant.sim import SimConfig, simulate

EIGHT = Path(__file__).resolve().parents[3] / "vehicles" / "example-8-onoff.toml"


def test_factors_of_a_timed_vehicle_are_one():
    v = Vehicle.load(EIGHT)
    v = dataclasses.replace(
        v, thrusters=tuple(dataclasses.replace(t, force_sigma_n=None) for t in v.thrusters),
        valves=dataclasses.replace(v.valves, delay_s=0.03, rise_s=0.015))
    cmd_t, duty = make_input("pulse-groups", 60.0, n_channels=8)
    hold_t, thrust = v.input_profile(cmd_t, duty)
    base = VehicleThrust(v, duty, v.arm_m, cmd_t=cmd_t)
    assert np.array_equal(base.hold_t, hold_t)
    np.testing.assert_allclose(base.factor_thrust((), ())[0], thrust, atol=1e-12)
    sim = simulate(cmd_t, duty, PlantParams(23.09, 0.31), None, SimConfig(seed=2),
                   thrust_n=thrust, thrust_t=hold_t)
    r = calibrate_thrust(sim.pose_t, sim.pose, cmd_t, duty, v, mass_kg=23.09, izz_kgm2=None,
                         mass_sigma_kg=0.0, per="common")
    assert r.converged
    assert abs(r.values[0] - 1.0) < 3.5 * r.sigma[0], (r.values, r.sigma)
    assert abs(r.izz["izz_kgm2"] - 0.31) < 3.5 * r.izz["izz_sigma_kgm2"]


def test_centre_of_mass_estimated_with_the_factors():
    v = Vehicle.load(EIGHT)
    v = dataclasses.replace(
        v, thrusters=tuple(dataclasses.replace(t, force_sigma_n=None) for t in v.thrusters),
        valves=dataclasses.replace(v.valves, delay_s=0.03, rise_s=0.015))
    cmd_t, duty = make_input("pulse-groups", 60.0, n_channels=8)
    hold_t, thrust = v.input_profile(cmd_t, duty)
    sim = simulate(cmd_t, duty, PlantParams(23.09, 0.31, cx=0.012, cy=-0.008), None,
                   SimConfig(seed=5), thrust_n=thrust, thrust_t=hold_t)
    r = calibrate_thrust(sim.pose_t, sim.pose, cmd_t, duty, v, mass_kg=23.09, izz_kgm2=None,
                         per="common", estimate_com=True)
    assert r.converged and set(r.extras) == {"cx", "cy"}
    assert abs(r.values[0] - 1.0) < 3.5 * r.sigma[0], (r.values, r.sigma)
    for name, true in (("cx", 0.012), ("cy", -0.008)):
        assert abs(r.extras[name] - true) < 3.5 * r.extras_sigma[name], (name, r.extras)
    assert abs(r.izz["izz_kgm2"] - 0.31) < 3.5 * r.izz["izz_sigma_kgm2"]
