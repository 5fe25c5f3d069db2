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


# issue 16: plausibility of thrust tables

_NEG = """unit = "gf"
duty_range = [5.0, 90.0]
[nozzles.1]
coefficients = [-9.0692, 1.0439, -0.0128, 7.88e-5]
"""


def test_negative_thrust_over_the_duty_range_is_refused(tmp_path):
    # Table 2's nozzles.1 is negative below ~9.8 %: a duty_range from 5 % gave 0 N silently
    p = tmp_path / "neg.toml"
    p.write_text(_NEG)
    with pytest.raises(UserError, match=r"neg.toml: \[nozzles.1\] gives negative thrust .* "
                                        r"at duty 5 % \(1 nozzle\(s\) open\)"):
        ThrustTable.load(p)


def test_sign_flipped_coefficients_are_refused(tmp_path):
    p = tmp_path / "flip.toml"
    p.write_text('unit = "gf"\n[nozzles.1]\ncoefficients = [1.0, 0.5]\n'
                 '[nozzles.2]\ncoefficients = [-1.0, -0.5]\n')
    with pytest.raises(UserError, match=r"\[nozzles.2\] gives negative thrust"):
        ThrustTable.load(p)


@pytest.mark.parametrize("text,match", [
    ('units = "gf"\nunit = "gf"\n[nozzles.1]\ncoefficients=[1.0]',
     "unknown key 'units' \\(did you mean 'unit'\\?\\)"),
    ('unit = "gf"\nduty-range = [10, 90]\n[nozzles.1]\ncoefficients=[1.0]',
     "unknown key 'duty-range' \\(did you mean 'duty_range'\\?\\)"),
    ('unit = "gf"\npressure = 60\n[nozzles.1]\ncoefficients=[1.0]',
     "did you mean 'pressure_psi'"),
    ('unit = "gf"\n[nozzles.1]\ncoefficients=[1.0]\ncoeficients=[2.0]',
     r"\[nozzles.1\]: unknown key 'coeficients' \(did you mean 'coefficients'\?\)"),
])
def test_misspelled_keys_are_errors_with_the_nearest_key(tmp_path, text, match):
    p = tmp_path / "typo.toml"
    p.write_text(text)
    with pytest.raises(UserError, match=match):
        ThrustTable.load(p)


def test_a_table_without_unit_is_refused(tmp_path):
    p = tmp_path / "nounit.toml"
    p.write_text("[nozzles.1]\ncoefficients=[1.0]\n")
    with pytest.raises(UserError, match="no unit"):
        ThrustTable.load(p)


def test_notes_and_fit_statistics_are_kept(tmp_path):
    p = tmp_path / "notes.toml"
    p.write_text('unit = "gf"\nsource = "bench 3"\nnotes = "x"\n[nozzles.1]\ncoefficients=[1.0]\n')
    assert ThrustTable.load(p).extra == {"source": "bench 3", "notes": "x"}


def test_a_dip_within_fit_accuracy_is_read_as_zero_not_refused(tmp_path):
    # a cubic fitted to emulated bench data dipped to -0.039 gf at 10 % for 4 nozzles
    # (0.1 % of its full scale, inside the fit's < 1 % accuracy): the demo's own table
    p = tmp_path / "dip.toml"
    p.write_text('unit = "gf"\nduty_range = [10.0, 90.0]\n[nozzles.1]\n'
                 'coefficients = [-1.639, 0.16]\n')  # -0.039 gf at 10 %, 12.8 gf at 90 %
    t = ThrustTable.load(p)
    assert t.per_nozzle(10.0, 1) < 0  # the polynomial itself dips (-0.039 gf)
    assert t.thrust_n([[10.0, 0, 0, 0]])[0, 0] == 0.0  # a nozzle cannot pull
    p.write_text('unit = "gf"\nduty_range = [10.0, 90.0]\n[nozzles.1]\n'
                 'coefficients = [-2.0, 0.16]\n')  # -0.4 gf of 12.4 gf: 3.2 % of full scale
    with pytest.raises(UserError, match="negative thrust"):
        ThrustTable.load(p)
