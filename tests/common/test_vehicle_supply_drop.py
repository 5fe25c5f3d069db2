"""A shared supply's drop for on/off valves (issue 24): ``[supplies.<name>]
drop_per_valve`` in vehicle.toml, its range check, its writing and its thrust."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from common.errors import UserError
from common.vehicle import Vehicle

EIGHT = Path(__file__).resolve().parents[2] / "vehicles" / "example-8-onoff.toml"


def _with_supplies(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "v.toml"
    path.write_text(EIGHT.read_text() + "\n" + text)
    return path


def test_drop_scales_each_open_valve_by_the_other_open_valves(tmp_path):
    v = Vehicle.load(_with_supplies(tmp_path, "[supplies.main]\ndrop_per_valve = 0.03\n"))
    base = Vehicle.load(EIGHT)
    duty = np.zeros((3, 8))
    duty[1, 0] = 100.0                     # one valve open: k = 1, no drop
    duty[2, [0, 2, 5]] = 100.0             # three open: each loses 2 x 3 %
    got, ref = v.thrust_n(duty), base.thrust_n(duty)
    assert np.array_equal(got[:2], ref[:2])
    np.testing.assert_allclose(got[2], ref[2] * np.where(duty[2] > 0, 0.94, 1.0), rtol=1e-15)


def test_no_drop_is_bit_for_bit_today(tmp_path):
    v = Vehicle.load(_with_supplies(tmp_path, "[supplies.main]\ndrop_per_valve = 0.0\n"))
    duty = np.random.default_rng(1).choice([0.0, 100.0], size=(50, 8))
    assert np.array_equal(v.thrust_n(duty), Vehicle.load(EIGHT).thrust_n(duty))


def test_drop_written_and_read_back(tmp_path):
    v = Vehicle.load(_with_supplies(tmp_path, "[supplies.main]\ndrop_per_valve = 0.02\n"
                                               "drop_sigma = 0.004\n"))
    out = tmp_path / "out"
    out.mkdir()
    back = Vehicle.load(v.write(out))
    assert back.supplies == v.supplies and back.drop_of("main") == 0.02
    assert any("drop 0.02 +- 0.004" in line for line in back.describe())


def test_drop_sigma_is_a_consider_parameter(tmp_path):
    v = Vehicle.load(_with_supplies(tmp_path, "[supplies.main]\ndrop_per_valve = 0.02\n"
                                               "drop_sigma = 0.004\n"))
    duty = np.zeros((2, 8))
    duty[1, [0, 1]] = 100.0
    s = v.thruster_sensitivity(duty)
    j = s.names.index("main:drop")
    assert s.covariance[j, j] == pytest.approx(0.004 ** 2)
    np.testing.assert_allclose(s.jacobian[1, :2, j], [-0.4415, -0.4502])
    assert not np.any(s.jacobian[0, :, j])


@pytest.mark.parametrize("text, key", [
    ("[supplies.main]\ndrop_per_valve = 0.2\n", "drop_per_valve must be >= 0 and < 1/(n-1)"),
    ("[supplies.main]\ndrop_per_valve = -0.01\n", "drop_per_valve must be >= 0"),
    ("[supplies.main]\ndrop_per_vale = 0.01\n", "did you mean 'drop_per_valve'"),
    ("[supplies.other]\ndrop_per_valve = 0.01\n", "names no supply of a thruster"),
])
def test_bad_drop_is_one_line_naming_file_and_key(tmp_path, text, key):
    with pytest.raises(UserError) as exc:
        Vehicle.load(_with_supplies(tmp_path, text))
    msg = str(exc.value)
    assert "\n" not in msg and str(tmp_path / "v.toml") in msg and "[supplies." in msg
    assert key in msg
