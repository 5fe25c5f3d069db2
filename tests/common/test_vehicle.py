"""vehicle.toml (issue 24): parsing, wrench, thrust models, valve timing, the TPODS vehicle
identical to today's module."""

from __future__ import annotations

import dataclasses
import tomllib
from pathlib import Path

import numpy as np
import pytest

from common.argtypes import VehicleFile
from common.errors import UserError
from common.layout import module_wrench_1, virtual_from_wrench
from common.layout_files import folder_layout, load_layout, load_structure_only
from common.runfolder import read_run, write_run
from common.structure import Structure
from common.thrust_table import ThrustTable
from common.thrust_uncertainty import ThrustUncertainty
from common.valve_timing import first_order_rise
from common.vehicle import Vehicle

ROOT = Path(__file__).resolve().parents[2]
TPODS = ROOT / "vehicles" / "tpods.toml"
EIGHT = ROOT / "vehicles" / "example-8-onoff.toml"

TWO = """
[vehicle]
name = "two"
[[thrusters]]
name = "A"
position_m = [0.1, 0.2]
direction = [0.0, 1.05]
force_n = 0.5
force_sigma_n = 0.01
[[thrusters]]
name = "B"
position_m = [-0.1, 0.0]
direction = [0.6, 0.8]
force_n = 0.4
"""


def _duties(n: int, rows: int = 200, seed: int = 3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    d = rng.uniform(10, 90, (rows, n))
    return np.where(rng.random((rows, n)) < 0.4, 0.0, d)


def test_tpods_vehicle_is_todays_module_bit_for_bit():
    v = Vehicle.load(TPODS)
    assert np.allclose(v.module_wrench_matrix(), module_wrench_1(), rtol=0, atol=1e-15)
    assert v.is_single_at_origin and v.n_channels == 4
    s = Structure.single_module()
    d = _duties(4)
    assert np.array_equal(v.virtual_thrust(d), s.virtual_thrust(d))
    t_v, th_v = v.input_profile(np.arange(len(d)) * 0.02, d)
    assert np.array_equal(th_v, s.virtual_thrust(d))
    table = dataclasses.replace(ThrustTable.default(), uncertainty=ThrustUncertainty(scale_rel=0.02))
    sv, ss = v.with_table(table).virtual_sensitivity(d), s.with_table(table).virtual_sensitivity(d)
    assert sv.names == ss.names == ("scale",)
    assert np.array_equal(sv.jacobian, ss.jacobian) and np.array_equal(sv.covariance, ss.covariance)


def test_a_tpods_vehicle_run_estimates_exactly_as_a_single_module_structure_run(tmp_path):
    from estimator.estimate import estimate_run
    from estimator.plant.inputs import phase_sine
    from estimator.plant.model import PlantParams
    from estimator.plant.sim import SimConfig, simulate

    cmd_t, duty = phase_sine(10.0)
    res = simulate(cmd_t, duty, PlantParams(2.268, 3.78e-3), None, SimConfig(seed=4))
    kw = dict(cmd_t=cmd_t, duty_pct=duty, pose_t=res.pose_t, pose=res.pose)
    plain = write_run(tmp_path / "plain", **kw, structure=Structure.single_module())
    veh = write_run(tmp_path / "veh", **kw, structure=Vehicle.load(TPODS))
    assert (veh / "vehicle.toml").is_file()
    a, b = read_run(plain), read_run(veh)
    assert isinstance(b.structure, Vehicle)
    for x, y in zip(a.thrust_profile(), b.thrust_profile(), strict=True):
        assert np.array_equal(x, y)
    ea = estimate_run(plain, None, estimate=("mass", "izz")).to_dict()
    eb = estimate_run(veh, None, estimate=("mass", "izz")).to_dict()
    for key in ("mass_kg", "izz_kgm2", "mass_sigma_kg", "izz_sigma_kgm2", "com_x_m", "com_y_m"):
        assert ea[key] == eb[key], key


def test_wrench_column_and_on_off_thrust():
    v = Vehicle.from_dict(tomllib.loads(TWO), "two.toml")
    assert v.thrusters[0].direction == (0.0, 1.0)  # normalised
    w = v.module_wrench_matrix()
    assert np.allclose(w[:, 0], [0.0, 1.0, 0.1 * 1.0 - 0.2 * 0.0])
    assert np.allclose(w[:, 1], [0.6, 0.8, -0.1 * 0.8 - 0.0 * 0.6])
    d = np.array([[100.0, 0.0], [50.0, 100.0], [0.0, 0.0]])
    assert np.allclose(v.thrust_n(d), [[0.5, 0.0], [0.25, 0.4], [0.0, 0.0]])
    # the virtual thrusts carry the vehicle's wrench
    assert np.allclose(v.virtual_thrust(d) @ module_wrench_1().T, v.thrust_n(d) @ w.T)
    s = v.virtual_sensitivity(d)
    assert s.names == ("A:force",) and np.allclose(s.covariance, [[1e-4]])
    assert np.allclose(s.jacobian[..., 0], (d[:, :1] / 100.0) @ v.virtual_matrix()[:, :1].T)


def test_a_table_drops_with_the_valves_open_on_its_supply(tmp_path):
    th = "\n".join(f"""[[thrusters]]
name = "T{i}"
position_m = [{0.1 * np.cos(i)}, {0.1 * np.sin(i)}]
direction = [{-np.sin(i)}, {np.cos(i)}]
thrust_table = "default"
supply = "{'a' if i < 3 else 'b'}"
""" for i in range(5))
    (tmp_path / "v.toml").write_text('[vehicle]\nname = "s"\n' + th)
    v = Vehicle.load(tmp_path / "v.toml")
    d = _duties(5)
    t = ThrustTable.default()
    want = np.hstack([t.thrust_n(d[:, :3]), t.thrust_n(d[:, 3:])])
    assert np.array_equal(v.thrust_n(d), want)
    assert not v.is_single_at_origin


@pytest.mark.parametrize("edit, message", [
    (("force_n = 0.5", "forse_n = 0.5"), "two.toml: [[thrusters]] 'A': unknown key 'forse_n' (did you mean 'force_n'?)"),
    (("force_n = 0.5", ""), "[[thrusters]] 'A': give either force_n"),
    (("force_n = 0.5", 'force_n = 0.5\nthrust_table = "default"'), "not both"),
    (("[0.0, 1.05]", "[0.0, 0.5]"), "direction must be a unit vector"),
    (('name = "two"', 'nmae = "two"'), "[vehicle]: unknown key 'nmae' (did you mean 'name'?)"),
    (('name = "B"', 'name = "A"'), "thruster name 'A' appears twice"),
    (("force_n = 0.4", 'thrust_table = "default"'), "supply 'main' mixes on/off force_n valves"),
    (("[vehicle]", "[valves]\ndelay_s = -1\n[vehicle]"), "[valves] delay_s must be >= 0"),
])
def test_a_bad_vehicle_file_is_one_line_naming_file_and_key(tmp_path, edit, message):
    f = tmp_path / "two.toml"
    f.write_text(TWO.replace(*edit, 1))
    with pytest.raises(UserError) as e:
        load_layout(VehicleFile(f))
    assert message in str(e.value) and str(f) in str(e.value) and "\n" not in str(e.value)


def test_write_and_load_round_trip(tmp_path):
    v = Vehicle.load(EIGHT)
    v2 = Vehicle.load(v.write(tmp_path))
    assert v2.thrusters == v.thrusters and v2.valves == v.valves and v2.body == v.body
    assert load_layout(tmp_path / "vehicle.toml").name == v.name
    assert folder_layout(tmp_path) == tmp_path / "vehicle.toml"
    (tmp_path / "structure.toml").write_text("")
    with pytest.raises(UserError, match="both structure.toml and vehicle.toml"):
        folder_layout(tmp_path)


def test_the_valve_delay_sigma_is_read_and_written_back(tmp_path):
    """``[valves] delay_sigma_s``: the stated 1-sigma of the delay (the live estimator warns
    against an unmeasured clock offset larger than it)."""
    v = Vehicle.load(EIGHT)
    v = dataclasses.replace(v, valves=dataclasses.replace(v.valves, delay_s=0.02,
                                                          delay_sigma_s=0.002))
    v2 = Vehicle.load(v.write(tmp_path))
    assert v2.valves.delay_sigma_s == 0.002 and v2.valves == v.valves


def test_valve_delay_shifts_every_switch(tmp_path):
    v = dataclasses.replace(Vehicle.load(EIGHT), valves=dataclasses.replace(Vehicle.load(EIGHT).valves,
                                                                             delay_s=0.03))
    cmd_t = np.array([0.0, 0.5, 1.0, 1.5])
    duty = np.zeros((4, 8))
    duty[0, 0] = duty[2, 1] = 100.0
    t, thr = v.input_profile(cmd_t, duty)
    assert np.allclose(t, [0.0, 0.03, 0.53, 1.03, 1.53])
    assert np.all(thr[0] == 0) and np.allclose(thr[1:], v.virtual_thrust(duty))


def test_first_order_rise_keeps_every_impulse_exact():
    tau = 0.02
    t = np.array([0.0, 0.013, 0.5, 0.61, 2.0])
    u = np.array([[1.0], [0.3], [0.0], [2.0], [0.0]])
    tt, ff = first_order_rise(t, u, tau)
    # the exact response's impulse over every command segment equals the hold's
    f = 0.0
    for i in range(len(t) - 1):
        seg_len = t[i + 1] - t[i]
        exact = u[i, 0] * seg_len + (f - u[i, 0]) * tau * (1 - np.exp(-seg_len / tau))
        f = u[i, 0] + (f - u[i, 0]) * np.exp(-seg_len / tau)
        inside = (tt[:-1] >= t[i]) & (tt[:-1] < t[i + 1])
        held = np.sum(np.diff(tt)[inside] * ff[:-1][inside, 0])
        assert abs(held - exact) < 1e-14
    assert tt[-1] == 2.0 and np.all(np.diff(tt) > 0)


def test_a_body_frame_wrench_is_exactly_its_virtual_thrusts():
    w = np.array([[0.3, -0.2, 0.01], [0.0, 0.0, -0.02]])
    assert np.allclose(virtual_from_wrench(w) @ module_wrench_1().T, w, rtol=0, atol=1e-15)


def test_a_structure_composes_vehicles(tmp_path):
    (tmp_path / "sat.toml").write_text(EIGHT.read_text())
    (tmp_path / "tp.toml").write_text(TPODS.read_text())
    (tmp_path / "s.toml").write_text('''name = "pair"
[[modules]]
name = "tpods1"
position_m = [-0.4, 0.0]
vehicle = "tp.toml"
[[modules]]
name = "sat"
position_m = [0.4, 0.1]
yaw_deg = 90.0
vehicle = "sat.toml"
''')
    s = load_layout(tmp_path / "s.toml")
    assert isinstance(s, Structure) and s.n_channels == 12 and not s.is_single_at_origin
    assert s.command_columns()[-1] == "d12"
    d = np.hstack([_duties(4), np.where(_duties(8, seed=5) > 0, 100.0, 0.0)])
    w = s.module_wrench_matrix()
    assert np.allclose(s.virtual_thrust(d) @ module_wrench_1().T, s.thrust_n(d) @ w.T, atol=1e-14)
    # the TPODS vehicle module is today's module: the same wrench as a plain module entry
    plain = Structure.from_dict({"name": "p", "modules": [
        {"name": "tpods1", "position_m": [-0.4, 0.0]}]})
    assert np.allclose(w[:, :4], plain.module_wrench_matrix(), rtol=0, atol=1e-15)
    # the satellite turned 90 degrees: its T1 pushes along -x of its body, i.e. -y here
    assert np.allclose(w[:2, 4], [0.0, -1.0], atol=1e-15)
    sens = s.virtual_sensitivity(d)
    assert "sat:T1:force" in sens.names
    (tmp_path / "copy").mkdir()
    again = load_layout(s.write(tmp_path / "copy"))
    assert np.array_equal(again.module_wrench_matrix(), w)
    assert (tmp_path / "copy" / "sat_vehicle.toml").is_file()
    with pytest.raises(UserError, match="does not take a vehicle yet"):
        load_structure_only(tmp_path / "s.toml", "tpods run play", "why")
