import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from bench.ohaus.driver import Reading, parse_line, parse_weight_line


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


# Issue 14: the row (b"   1.234 N", 1.234, "N", True) used to sit in test_parses_scout_variants.
# A lone N after the number is the unit newton or, with print unit off, the net legend
# (Defender 5000 manual, 5.5): read by the unit verified on the balance, never guessed.
def test_lone_n_is_read_by_the_verified_unit():
    line = b"   1.234 N"
    res = parse_line(line)
    assert res.kind == "refused" and "ambiguous" in res.reason and res.reading is None
    assert parse_weight_line(line, unit="N") == Reading(1.234, "N", True)
    assert parse_weight_line(line, unit="g") == Reading(1.234, "g", True, legend="net")
    assert parse_weight_line(b"   1.234 N N", unit="g") == Reading(1.234, "N", True, legend="net")


@pytest.mark.parametrize("line, legend", [
    (b"   12.34 g   N\r\n", "net"),
    (b"   12.34 g ? NET", "net"),
    (b"   12.34 g   Net", "net"),
    (b"   12.34 g   G", "gross"),
    (b"   12.34 g   B/G", "gross"),
    (b"   12.34 g   GROSS", "gross"),
    (b"      12.34 g\r\n", None),
])
def test_gross_and_net_keep_their_value_and_say_which(line, legend):
    r = parse_weight_line(line)
    assert r is not None and r.value == 12.34 and r.unit == "g" and r.legend == legend


@pytest.mark.parametrize("line, kind", [
    (b"     0.50 kg    T  ", "tare"),
    (b"     0.50 kg    Tare", "tare"),
    (b"      0.500    kg   PT", "preset tare"),
    (b"     207.80 g TOTAL", "total"),
    (b"T             0.50 kg", "tare"),
])
def test_tare_preset_tare_and_totals_are_not_load_readings(line, kind):
    res = parse_line(line)
    assert parse_weight_line(line) is None
    assert (res.kind, res.legend) == ("not_load", kind) and kind in res.reason


@pytest.mark.parametrize("line, reason", [
    (b"      1.234         G", "no unit field"),
    (b"   12.34 g   G N", "ambiguous"),
    (b"  12.3", "ambiguous"),
    (b"12.34 furlong", "unknown unit 'furlong'"),
    (b"12.34 g xyz", "unknown field 'xyz'"),
    (b"\xa5\xa5 g ?", "ASCII"),
    (b"", "empty"),
])
def test_refusals_say_why(line, reason):
    res = parse_line(line)
    assert res.kind == "refused" and res.reading is None and reason in res.reason


def test_unit_off_lines_use_the_verified_unit_only():
    line = b"      1.234         N"
    assert parse_weight_line(line) is None
    assert parse_weight_line(line, unit="kg") == Reading(1.234, "kg", True, legend="net")
    assert parse_weight_line(b"      1.234       ? G", unit="g") == Reading(1.234, "g", False, legend="gross")
    # a printed unit wins over the verified one
    assert parse_weight_line(b"    1.234 kg   NET", unit="g") == Reading(1.234, "kg", True, legend="net")
