import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from bench.ohaus import Reading, parse_weight_line


@pytest.mark.parametrize("line, value, unit, stable", [
    (b"      12.34 g\r\n", 12.34, "g", True),             # Scout
    (b"      12.34 g ?\r\n", 12.34, "g", False),          # Scout, unstable
    (b"     -0.05 g\r\n", -0.05, "g", True),
    (b"-     3.10 g  ?", -3.10, "g", False),              # sign left-justified
    (b"    0.01234 kg", 0.01234, "kg", True),
    ("   12.3400 g    ", 12.34, "g", True),               # Scout Pro trailing blanks
    (b"   12.34 g   N\r\n", 12.34, "g", True),            # Navigator net indicator
    (b"   12.34 g ? NET", 12.34, "g", False),
    (b"12.34g?", 12.34, "g", False),                      # glued
    (b"   +7,50 g", 7.5, "g", True),                      # decimal comma
    (b"  0.4321 oz", 0.4321, "oz", True),
    (b"? 12.34 g", 12.34, "g", False),
    (b"   1.234 N", 1.234, "N", True),
])
def test_parses_scout_variants(line, value, unit, stable):
    r = parse_weight_line(line)
    assert r is not None
    assert r.value == pytest.approx(value) and r.unit == unit and r.stable is stable


@pytest.mark.parametrize("line", [
    b"", b"\r\n", b"  12.3", b"12.34", b"#?!", b"\x00\xff\xfe", b"\xa5\xa5 g ?", b"1.2.3.4 g",
    b"ES", b"OK!", b"12.34 g xyz", b"12.34 furlong", b"g 12.34", b"-------- g", b"nan g",
    b"12.34 g\x07",
])
def test_rejects_garbage_and_partial_lines(line):
    assert parse_weight_line(line) is None


@given(st.floats(-9999, 9999, allow_nan=False), st.booleans(), st.sampled_from(["g", "kg", "oz"]))
def test_roundtrip_of_formatted_readings(v, stable, unit):
    line = f"{v:10.2f} {unit}" + ("" if stable else " ?") + "\r\n"
    r = parse_weight_line(line.encode())
    assert r is not None
    assert r.value == pytest.approx(round(v, 2), abs=1e-9) and r.unit == unit and r.stable is stable


def test_grams_conversion():
    assert Reading(0.5, "kg", True).grams == pytest.approx(500.0)
    assert Reading(1.0, "PCS", True).grams is None
    assert math.isnan(Reading(1.0, "g", True).t)
