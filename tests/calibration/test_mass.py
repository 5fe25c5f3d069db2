"""Mass from readings: GUM budget by hand, parsing, stable-reading collection."""

import math

import pytest

from calibration.mass import (
    mass_from_readings,
    parse_readings_text,
    readings_from_iterable,
    take_readings,
    to_kg,
)
from common.errors import DeviceError, UserError


def test_gum_budget_by_hand():
    # readings 720.0, 720.2, 720.4 g: mean 720.2 g, s = 0.2 g, u_A = 0.2/sqrt(3) = 0.11547 g
    # +-2.5 g rectangular: u_B = 2.5/sqrt(3) = 1.44338 g; u_c = sqrt(0.11547^2 + 1.44338^2)
    r = mass_from_readings([0.7200, 0.7202, 0.7204], 2.5e-3)
    assert r.mass_kg == pytest.approx(0.7202)
    assert r.std_kg == pytest.approx(0.2e-3)
    assert r.u_typeA_kg == pytest.approx(0.115470e-3, rel=1e-5)
    assert r.u_typeB_kg == pytest.approx(1.443376e-3, rel=1e-6)
    assert r.u_combined_kg == pytest.approx(1.447987e-3, rel=1e-5)
    assert r.expanded_kg == pytest.approx(2 * r.u_combined_kg)
    # resolution d = 0.1 g adds d / (2 sqrt 3) = 0.028868 g in quadrature
    r2 = mass_from_readings([0.7200, 0.7202, 0.7204], 2.5e-3, resolution_kg=1e-4)
    assert r2.u_combined_kg == pytest.approx(math.hypot(r.u_combined_kg, 0.028868e-3), rel=1e-5)


def test_bad_readings_refused():
    for vals, msg in (([0.72], "at least 2"), ([0.72, -0.1], "positive"),
                      ([0.72, float("nan")], "finite")):
        with pytest.raises(UserError, match=msg):
            mass_from_readings(vals, 2.5e-3)


def test_parse_text_units_comments_and_unstable():
    text = "# hand log\n720.1\n  720.3 g\n0.7199 kg, 720.2\n      720.9 g ?\n\n"
    vals, unstable = parse_readings_text(text)
    assert vals == pytest.approx([0.7201, 0.7203, 0.7199, 0.7202])
    assert unstable == 1
    assert parse_readings_text("1.5875 lb", "g")[0] == pytest.approx([1.5875 * 0.45359237])
    with pytest.raises(UserError, match="line 2"):
        parse_readings_text("720.1\nseven hundred\n")
    with pytest.raises(UserError, match="unit"):
        to_kg(1.0, "stone")


class _R:
    def __init__(self, value, unit, stable, grams=None):
        self.value, self.unit, self.stable = value, unit, stable
        if grams is not None:
            self.grams = grams


def test_take_readings_skips_unstable_and_garbage():
    seq = [(720.1, "g", True), (733.0, "g", False), _R(720.3, "g", True, grams=720.3),
           DeviceError("garbage"), _R(0.7202, "kg", True)]

    it = iter(seq)

    def read():
        item = next(it)
        if isinstance(item, Exception):
            raise item
        return item

    vals, skipped = take_readings(read, 3)
    assert vals == pytest.approx([0.7201, 0.7203, 0.7202]) and skipped == 2
    with pytest.raises(DeviceError, match="stable readings"):
        take_readings(readings_from_iterable([(720.0, "g", False)] * 10), 2)
    with pytest.raises(UserError, match="at least 2"):
        take_readings(read, 1)


# issue 16: decimal commas read as two readings (720,1 -> 720 and 1), a BOM refused

def test_decimal_comma_is_refused_clearly():
    with pytest.raises(UserError, match=r"r.txt: line 1: '720,1': a decimal comma\? write 720.1"):
        parse_readings_text("720,1\n720,3\n", "g", "r.txt")


def test_comma_and_space_still_separate_readings():
    vals, _ = parse_readings_text("720.1, 720.3\n720.2,\n", "g")
    assert vals == pytest.approx([0.7201, 0.7203, 0.7202])


def test_a_bom_is_accepted():
    vals, _ = parse_readings_text("\ufeff720.1\n720.3 g\n", "g")
    assert vals == pytest.approx([0.7201, 0.7203])
