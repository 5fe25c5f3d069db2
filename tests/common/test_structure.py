"""common.structure: structure.toml, per-module thrust, virtual thrusts (issue 18)."""

import math

import numpy as np
import pytest

from common.constants import ARM_M, GF_TO_N
from common.errors import UserError
from common.structure import Module, Structure
from common.thrust_table import ThrustTable

TWO = """
name = "truss"
[[modules]]
name = "tpods1"
position_m = [-0.25, 0.0]
yaw_deg = 0
[[modules]]
name = "tpods2"
position_m = [0.25, 0.05]
yaw_deg = 180
mass_kg = 0.72
[body]
mass_kg = 1.9
mass_sigma_kg = 0.01
com_m = [0.03, 0.0]
com_sigma_m = 0.005
"""


def write(tmp_path, text, name="structure.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def module_wrench_by_hand(t, x, y, yaw_deg, d=ARM_M):
    """Fx, Fy, Mz about the tracked origin of one module's four thrusts (written apart
    from common.structure: forces per thruster direction, then r x F summed)."""
    s = 1 / math.sqrt(2)
    # thruster force directions in the module frame (docs/run-format.md geometry)
    dirs = [(-s, s), (s, s), (s, -s), (-s, -s)]
    spin = [1, -1, 1, -1]
    a = math.radians(yaw_deg)
    fx = fy = mz = 0.0
    for ti, (dx, dy), sp in zip(t, dirs, spin, strict=True):
        bx = ti * (math.cos(a) * dx - math.sin(a) * dy)
        by = ti * (math.sin(a) * dx + math.cos(a) * dy)
        fx += bx
        fy += by
        mz += sp * d * ti + x * by - y * bx
    return np.array([fx, fy, mz])


def test_parse_two_modules(tmp_path):
    s = Structure.load(write(tmp_path, TWO))
    assert s.name == "truss" and s.n_modules == 2 and s.n_channels == 8
    assert [m.name for m in s.modules] == ["tpods1", "tpods2"]
    assert s.modules[1].position_m == (0.25, 0.05) and s.modules[1].yaw_deg == 180.0
    assert s.modules[1].mass_kg == 0.72 and s.modules[0].mass_kg is None
    assert s.modules[0].table == ThrustTable.default() and s.modules[0].table_path is None
    assert s.body.mass_kg == 1.9 and s.body.com_m == (0.03, 0.0)
    assert s.body.com_sigma_m == (0.005, 0.005)
    assert s.command_columns() == ("t", "d1", "d2", "d3", "d4", "d5", "d6", "d7", "d8")


def test_thrust_table_relative_to_file_and_written_self_contained(tmp_path):
    sub = tmp_path / "cfg"
    sub.mkdir()
    t = ThrustTable({1: (0.0, 0.01)}, unit="N", duty_range=(10.0, 90.0))
    t.save(sub / "t1.toml")
    text = TWO.replace('name = "tpods1"', 'name = "tpods1"\nthrust_table = "t1.toml"')
    s = Structure.load(write(sub, text))
    assert s.modules[0].table.coefficients == {1: (0.0, 0.01)}
    assert s.modules[0].table_path == sub / "t1.toml"
    out = tmp_path / "run"
    out.mkdir()
    s.write(out)
    back = Structure.load(out / "structure.toml")
    assert back.modules[0].table.coefficients == {1: (0.0, 0.01)}
    assert back.modules[1].position_m == s.modules[1].position_m and back.body == s.body


@pytest.mark.parametrize("text, match", [
    ('name = "x"\nmodule = []', r"unknown key 'module' \(did you mean 'modules'\?\)"),
    ('name = "x"\n[[modules]]\nname = "a"\npositon_m = [0, 0]',
     r"unknown key 'positon_m' \(did you mean 'position_m'\?\)"),
    ('name = "x"\n[[modules]]\nname = "a"\nposition_m = [0, 0]\n[body]\nmass = 1',
     r"\[body\]: unknown key 'mass' \(did you mean 'mass_kg'\?\)"),
    ('[[modules]]\nname = "a"\nposition_m = [0, 0]', "no name"),
    ('name = "x"', "no modules"),
    ('name = "x"\n[[modules]]\nname = "a"', "no position_m"),
    ('name = "x"\n[[modules]]\nname = "a"\nposition_m = [0]', r"position_m must be two numbers"),
    ('name = "x"\n[[modules]]\nname = "a b"\nposition_m = [0, 0]', "name must be letters"),
    ('name = "x"\n[[modules]]\nname = "a"\nposition_m = [0, 0]\n[[modules]]\nname = "a"\n'
     'position_m = [1, 0]', "appears twice"),
    ('name = "x"\n[[modules]]\nname = "a"\nposition_m = [0, 0]\nmass_kg = -1', "must be positive"),
    ('name = "x"\n[[modules]]\nname = "a"\nposition_m = [0, 0]\nthrust_table = "nope.toml"',
     "nope.toml: thrust table not found"),
    ('name = "x"\n[[modules]]\nname = "a"\nposition_m = [0, 0]\n[body]\ncom_sigma_m = 0.1',
     "com_sigma_m given without com_m"),
    ('name = "x"\n[[modules]\n', "not valid TOML"),
])
def test_refusals_are_one_line_naming_the_file(tmp_path, text, match):
    p = write(tmp_path, text)
    with pytest.raises(UserError, match=match) as e:
        Structure.load(p)
    msg = str(e.value)
    assert msg.startswith(str(p)) and "\n" not in msg


def test_missing_file(tmp_path):
    with pytest.raises(UserError, match="structure file not found"):
        Structure.load(tmp_path / "none.toml")


def test_single_module_gives_the_tables_thrusts_bit_for_bit():
    table = ThrustTable.default()
    s = Structure.single_module(table)
    rng = np.random.default_rng(1)
    duty = np.where(rng.random((200, 4)) < 0.3, 0.0, rng.uniform(10, 90, (200, 4)))
    assert np.array_equal(s.virtual_thrust(duty), table.thrust_n(duty))
    assert np.array_equal(s.thrust_n(duty), table.thrust_n(duty))
    sens = s.virtual_sensitivity(duty)
    assert np.array_equal(sens.thrust_n, table.thrust_n(duty)) and sens.empty


@pytest.mark.parametrize("yaws", [(0.0, 180.0), (30.0, -75.0), (90.0, 90.0)])
def test_virtual_thrust_reproduces_the_structures_wrench(yaws):
    from estimator.plant.model import wrench

    mods = (Module("a", (-0.25, 0.02), yaws[0]), Module("b", (0.31, -0.07), yaws[1]))
    s = Structure("truss", mods)
    rng = np.random.default_rng(2)
    duty = np.where(rng.random((50, 8)) < 0.3, 0.0, rng.uniform(10, 90, (50, 8)))
    phys = s.thrust_n(duty)
    expected = np.array([sum(module_wrench_by_hand(row[4 * i:4 * i + 4], *m.position_m, m.yaw_deg)
                             for i, m in enumerate(mods)) for row in phys])
    v = s.virtual_thrust(duty)
    assert v.shape == (50, 4)
    np.testing.assert_allclose(wrench(v, ARM_M), expected, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(s.module_wrench_matrix() @ phys.T, expected.T, rtol=1e-12, atol=1e-14)


def test_module_rotated_90_at_0_3_by_hand():
    s = Structure("one", (Module("a", (0.3, 0.0), 90.0),))
    table = ThrustTable({1: (0.0, 0.01)}, unit="N")  # 0.5 N at 50 %
    s = s.with_table(table)
    v = s.virtual_thrust(np.array([50.0, 0, 0, 0]))
    # T1 = 0.5 N pushes (-x + y)/sqrt2 in the module frame; turned 90 deg: (-x - y)/sqrt2
    f = 0.5 / math.sqrt(2)
    from estimator.plant.model import wrench

    np.testing.assert_allclose(wrench(v), [-f, -f, 0.05 * 0.5 + 0.3 * -f], atol=1e-15)
    np.testing.assert_allclose(s.module_wrench_matrix()[:, 0],
                               [-1 / math.sqrt(2), -1 / math.sqrt(2), 0.05 - 0.3 / math.sqrt(2)])


def test_each_module_uses_its_own_open_count():
    t = ThrustTable.default()
    s = Structure("truss", (Module("a", (-0.2, 0.0), 0.0), Module("b", (0.2, 0.0), 0.0)))
    duty = np.array([50.0, 50.0, 0, 0, 0, 0, 60.0, 0])
    th = s.thrust_n(duty)
    assert th[0] == pytest.approx(t.per_nozzle(50.0, 2) * GF_TO_N, rel=1e-12)
    assert th[1] == th[0]
    assert th[6] == pytest.approx(t.per_nozzle(60.0, 1) * GF_TO_N, rel=1e-12)  # k = 1, not 3
    assert th[[2, 3, 4, 5, 7]].tolist() == [0, 0, 0, 0, 0]


def test_module_tables_and_errors_name_the_module():
    small = ThrustTable({1: (0.0, 0.01), 2: (0.0, 0.005)}, unit="N", duty_range=(20.0, 80.0))
    s = Structure("truss", (Module("a", (0, 0), 0.0), Module("b", (0.2, 0), 0.0, small, None)))
    th = s.thrust_n(np.array([50.0, 0, 0, 0, 50.0, 0, 0, 0]))
    assert th[4] == pytest.approx(0.5)
    with pytest.raises(UserError, match=r"module b \(d5..d8\): duty 15 % is outside"):
        s.thrust_n(np.array([50.0, 0, 0, 0, 15.0, 0, 0, 0]))
    with pytest.raises(UserError, match="need 8 duty columns"):
        s.virtual_thrust(np.zeros((3, 4)))


def test_virtual_sensitivity_maps_each_modules_jacobian():
    unc = ThrustTable.from_dict({**ThrustTable.default().to_dict(), "uncertainty": {"scale_rel": 0.02}})
    s = Structure("truss", (Module("a", (-0.25, 0), 0.0, unc, None), Module("b", (0.25, 0), 90.0)))
    rng = np.random.default_rng(3)
    duty = rng.uniform(10, 90, (20, 8))
    sens = s.virtual_sensitivity(duty)
    assert sens.names == ("a:scale",)  # Table 2 (module b) states none
    np.testing.assert_allclose(sens.thrust_n, s.virtual_thrust(duty), rtol=1e-12, atol=1e-15)
    # a scale error of module a moves only module a's share of the virtual thrusts
    eps = 1e-6
    phys = s.thrust_n(duty)
    phys[:, :4] *= 1 + eps
    fd = (s.virtual_from_thrust(phys) - s.virtual_thrust(duty)) / eps
    np.testing.assert_allclose(sens.jacobian[..., 0], fd, rtol=1e-6, atol=1e-12)
    assert sens.covariance.shape == (1, 1) and sens.covariance[0, 0] == pytest.approx(4e-4)


def test_with_table_applies_to_modules_without_their_own(tmp_path):
    s = Structure.load(write(tmp_path, TWO))
    t = ThrustTable({1: (0.0, 0.01)}, unit="N")
    assert all(m.table is t for m in s.with_table(t).modules)


# ---------------------------------------------------------------- run folders


def structure_run(tmp_path, text=TWO, **kw):
    from common.runfolder import write_run

    s = Structure.load(write(tmp_path, text, "s.toml"))
    cmd_t = np.array([0.0, 1.0, 2.0])
    duty = np.array([[50.0, 0, 50, 0, 0, 60, 0, 0], [0, 40, 0, 40, 70, 0, 0, 0], [0.0] * 8])
    pose_t = np.linspace(0, 2, 5)
    run = write_run(tmp_path / "run", cmd_t=cmd_t, duty_pct=duty, pose_t=pose_t,
                    pose=np.zeros((5, 3)), structure=s, **kw)
    return s, run, duty


def test_structure_run_round_trip_gives_virtual_thrusts(tmp_path):
    from common.runfolder import read_run

    s, path, duty = structure_run(tmp_path)
    assert (path / "structure.toml").is_file()
    assert (path / "commands.csv").read_text().splitlines()[0] == "t,d1,d2,d3,d4,d5,d6,d7,d8"
    run = read_run(path)
    assert run.structure is not None and run.structure.n_channels == 8
    assert run.duty_pct.shape == (3, 8)
    t, v = run.thrust_profile()
    np.testing.assert_array_equal(v, s.virtual_thrust(duty))
    assert run.window(0.5, 2.0).structure is run.structure
    assert run.thrust_sensitivity() is None  # Table 2 states no uncertainty
    # an explicit table replaces the default of modules without their own
    tab = ThrustTable({1: (0.0, 0.01), 2: (0.0, 0.01)}, unit="N")
    _, v2 = run.thrust_profile(tab)
    np.testing.assert_allclose(v2, s.with_table(tab).virtual_thrust(duty))
    assert not np.allclose(v2, v)


def test_structure_run_needs_4n_columns(tmp_path):
    from common.runfolder import read_run, write_run

    s = Structure.load(write(tmp_path, TWO, "s.toml"))
    write_run(tmp_path / "r", cmd_t=np.array([0.0, 1.0]), duty_pct=np.zeros((2, 4)),
              pose_t=np.array([0.0, 1.0]), pose=np.zeros((2, 3)))
    with pytest.raises(UserError, match=r"commands.csv: missing column\(s\) d5, d6, d7, d8"):
        read_run(tmp_path / "r", structure=s)
    with pytest.raises(UserError, match="structure file not found"):
        read_run(tmp_path / "r", structure=tmp_path / "none.toml")
    run = read_run(tmp_path / "r")  # without a structure: a single-module run as today
    assert run.structure is None and run.duty_pct.shape == (2, 4)


def test_body_values_are_known_or_priors(tmp_path):
    """[body]: no sigma or sigma 0 is known, a sigma is a prior, per centre-of-mass axis."""
    s = Structure.load(write(tmp_path, TWO))
    assert s.body.known() == {} and s.body.priors() == {
        "mass": (1.9, 0.01), "cx": (0.03, 0.005), "cy": (0.0, 0.005)}
    text = TWO.split("[body]")[0] + ("[body]\nmass_kg = 1.9\nizz_kgm2 = 0.05\nizz_sigma_kgm2 = 0\n"
                                     "com_m = [0.03, 0.01]\ncom_sigma_m = [0, 0.002]\n")
    b = Structure.load(write(tmp_path, text, "mixed.toml")).body
    assert b.known() == {"mass": 1.9, "izz": 0.05, "cx": 0.03}
    assert b.priors() == {"cy": (0.01, 0.002)}
