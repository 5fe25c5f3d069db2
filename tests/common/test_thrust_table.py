import numpy as np
import pytest

from common.errors import UserError
from common.thrust_table import GF_TO_N, ThrustTable, load_thrust_table


def test_table2_values():
    t = ThrustTable.default()
    assert t.unit == "gf" and t.duty_range == (10.0, 90.0) and t.pressure_psi == 60.0
    assert t.per_nozzle(50.0, 1) == pytest.approx(20.976, abs=1e-3)
    assert t.per_nozzle(90.0, 1) == pytest.approx(38.66, abs=0.05)  # shared README: ~38.7 gf
    assert t.coefficients[3] == (-6.6022, 0.7555, -0.0096, 6.11e-5)


def test_nozzle_count_selects_polynomial():
    t = ThrustTable.default()
    one = t.thrust_n(np.array([50.0, 0, 0, 0]))
    two = t.thrust_n(np.array([50.0, 50.0, 0, 0]))
    four = t.thrust_n(np.array([50.0, 50.0, 50.0, 50.0]))
    assert one[0] == pytest.approx(t.per_nozzle(50, 1) * GF_TO_N)
    assert two[0] == pytest.approx(t.per_nozzle(50, 2) * GF_TO_N)
    assert four[3] == pytest.approx(t.per_nozzle(50, 4) * GF_TO_N)
    assert one[1:].tolist() == [0, 0, 0]
    assert one[0] > two[0]  # shared supply: fewer per-nozzle newtons with more open
    # row-wise selection in a batch
    batch = t.thrust_n(np.array([[50.0, 0, 0, 0], [50.0, 50.0, 50.0, 50.0]]))
    np.testing.assert_allclose(batch[0], one)
    np.testing.assert_allclose(batch[1], four)


def test_out_of_range_duty_is_refused_or_clamped():
    t = ThrustTable.default()
    with pytest.raises(UserError, match="outside"):
        t.thrust_n(np.array([5.0, 0, 0, 0]))
    with pytest.raises(UserError, match="outside"):
        t.thrust_n(np.array([95.0, 0, 0, 0]))
    clamped = t.thrust_n(np.array([95.0, 0, 0, 0]), clamp=True)
    assert clamped[0] == pytest.approx(t.per_nozzle(90, 1) * GF_TO_N)
    with pytest.raises(UserError):
        t.thrust_n(np.array([np.nan, 0, 0, 0]))


def test_toml_round_trip(tmp_path):
    t = ThrustTable({1: (1.0, 0.5), 2: (0.5, 0.25)}, "N", (5.0, 95.0), 55.0, {"fit_rms": 0.1})
    p = tmp_path / "t.toml"
    t.save(p)
    back = ThrustTable.load(p)
    assert back == t
    assert load_thrust_table(None) == ThrustTable.default()


@pytest.mark.parametrize("text,match", [
    ("unit = 'gf'", "malformed"),
    ("unit = 'lbf'\n[nozzles.1]\ncoefficients=[1.0]", "unit"),
    ("[nozzles.1]\ncoefficients=['a']", "malformed"),
    ("duty_range=[50.0, 10.0]\n[nozzles.1]\ncoefficients=[1.0]", "duty_range"),
    ("this is = not toml = ", "TOML"),
])
def test_bad_tables_are_refused(tmp_path, text, match):
    p = tmp_path / "bad.toml"
    p.write_text(text)
    with pytest.raises(UserError, match=match):
        ThrustTable.load(p)


def test_missing_table(tmp_path):
    with pytest.raises(UserError, match="not found"):
        ThrustTable.load(tmp_path / "nope.toml")
