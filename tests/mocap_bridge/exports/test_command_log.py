"""Command logs as labs write them (mocap_bridge/exports/command_log.py).

Real bytes, both from AevarOfjord/mpc-air-bearing-satellite at
44b2d08b15e301305bc23a6bbacae63899440252 (MIT; runs/fixtures/real/aevarofjord-air-bearing/):
- [RUN] Data/Real_Test/Test/real_test_data.csv: ``Command_Vector`` as the text
  ``"[1, 0, 1, 0, 1, 0, 1, 0]"`` (real.py:644) and ``Command_Hex`` = ``"0x"`` + the 8 states
  as binary digits (real.py:559: not hex);
- [THR] Thruster_Test/Thruster_Data/MPC_Thruster(8)_20250707_221229.csv lines 1-2, 175-179,
  676-679: the load-cell log, ``bitmask`` decimal with bit N-1 for thruster N
  (THRUSTER_CALIBRATION.md), thruster 8 = 128.
The per-valve, duty and wrench layouts are written here as the module doc defines them.
"""

from __future__ import annotations

import numpy as np
import pytest

from common.errors import UserError
from mocap_bridge.exports.command_log import (
    command_keys,
    parse_mask,
    parse_vector,
    read_command_log,
    shift_to_origin,
)
from mocap_bridge.exports.generic_csv import parse_column_map

RUN = (
    "Control_Time,Command_Vector,Command_Hex\n"
    '0.0,"[1, 0, 1, 0, 1, 0, 1, 0]",0x10101010\n'
    '0.06,"[0, 0, 1, 0, 1, 1, 1, 0]",0x00101110\n'
    '0.12,"[0, 0, 0, 0, 0, 0, 0, 1]",0x00000001\n'
)
THR = (
    "t_s,weight_g,bitmask,pulse_number,phase\n"
    "0.000,,0,0,baseline\n"
    "3.460,0.00,0,1,pre_pulse\n3.480,0.00,0,1,pre_pulse\n3.500,0.00,0,1,pre_pulse\n"
    "3.520,0.00,128,1,firing\n3.540,0.00,128,1,firing\n"
    "13.480,49.90,128,1,firing\n13.500,49.90,128,1,firing\n"
    "13.520,49.90,0,1,post_pulse\n13.540,49.90,0,1,post_pulse\n"
)


def _read(text, cols, n=8, **kw):
    return read_command_log(text, parse_column_map(cols, command_keys(n)), n_valves=n, what="log.csv", **kw)


def test_valve_vectors_are_recognised_and_end_one_step_later():
    c = _read(RUN, "t=Control_Time,valves=Command_Vector", time_unit="s")
    assert c.kind == "duty"
    np.testing.assert_allclose(c.t_s, [0.0, 0.06, 0.12, 0.18])
    np.testing.assert_array_equal(c.values[0], [100, 0, 100, 0, 100, 0, 100, 0])
    np.testing.assert_array_equal(c.values[2], [0, 0, 0, 0, 0, 0, 0, 100])
    np.testing.assert_array_equal(c.values[3], c.values[2])  # the end row holds the last state
    assert c.source["format"] == "command-log/vector"
    assert c.counts["end_row_step_s"] == pytest.approx(0.06)


def test_the_fake_hex_column_is_refused_as_hex_and_read_as_bits():
    with pytest.raises(UserError, match=r"log.csv: line 2, column 3 \(Command_Hex\): '0x10101010' sets bits beyond valve 8"):
        _read(RUN, "t=Control_Time,valves=Command_Hex", form="hex", time_unit="s")
    bits = _read(RUN, "t=Control_Time,valves=Command_Hex", form="bits", time_unit="s")
    vec = _read(RUN, "t=Control_Time,valves=Command_Vector", time_unit="s")
    np.testing.assert_array_equal(bits.values, vec.values)


def test_a_hex_column_of_binary_digits_is_read_but_warned_about():
    text = "t_s,h\n0,0x00000001\n1,0x00000010\n"
    c = _read(text, "t=t_s,valves=h", form="hex")
    np.testing.assert_array_equal(c.values[:2, :5], [[100, 0, 0, 0, 0], [0, 0, 0, 0, 100]])
    assert "--as bits" in c.warnings[0]


def test_integer_bitmask_of_the_load_cell_log():
    c = _read(THR, "t=t_s,valves=bitmask", form="bitmask")
    assert c.source["units"] == {"time": "s"}
    np.testing.assert_array_equal(c.values[:, 7], [0, 0, 0, 0, 100, 100, 100, 100, 0, 0, 0])
    np.testing.assert_array_equal(c.values[:, :7], 0)
    assert c.t_s[-1] == pytest.approx(13.56)


def test_hex_bitmask_bit_i_is_valve_i_plus_1():
    assert parse_mask("0x05", 4, "hex", "w") == [1, 0, 1, 0]
    assert parse_mask("0xA", 4, "hex", "w") == [0, 1, 0, 1]
    assert parse_mask("6", 4, "bitmask", "w") == [0, 1, 1, 0]
    assert parse_mask("0x0110", 4, "bits", "w") == [0, 1, 1, 0]
    with pytest.raises(UserError, match=r"w: '16' sets bits beyond valve 4"):
        parse_mask("16", 4, "bitmask", "w")
    with pytest.raises(UserError, match=r"w: '0xZZ' is not a hexadecimal number"):
        parse_mask("0xZZ", 4, "hex", "w")
    with pytest.raises(UserError, match=r"w: '0x012' is not 4 binary digits"):
        parse_mask("0x012", 4, "bits", "w")


def test_vector_errors_name_the_cell():
    with pytest.raises(UserError, match=r"w: 3 valve states in '\[1, 0, 1\]', the vehicle has 4 valves"):
        parse_vector("[1, 0, 1]", 4, "w")
    with pytest.raises(UserError, match=r"w: valve state '2' is not 0 or 1"):
        parse_vector("[1, 0, 2, 0]", 4, "w")
    with pytest.raises(UserError, match=r"w: '1, 0' is not a vector"):
        parse_vector("1, 0", 2, "w")


def test_per_valve_on_off_and_duty_columns():
    text = "time_ms,A,B\n0,1,0\n500,0,1\n"
    c = _read(text, "t=time_ms,d1=A,d2=B", n=2, form="columns")
    np.testing.assert_allclose(c.t_s, [0.0, 0.5, 1.0])
    np.testing.assert_array_equal(c.values, [[100, 0], [0, 100], [0, 100]])
    text = "time_ms,A,B\n0,25,0\n500,0,62.5\n"
    d = _read(text, "t=time_ms,d1=A,d2=B", n=2, form="duty")
    np.testing.assert_array_equal(d.values[:2], [[25, 0], [0, 62.5]])
    with pytest.raises(UserError, match=r"line 2, column 2 \(A\): duty 125 % is outside 0..100"):
        _read("t_s,A,B\n0,125,0\n1,0,0\n", "t=t_s,d1=A,d2=B", n=2, form="duty")
    with pytest.raises(UserError, match=r"--as columns needs d2=COL"):
        _read(text, "t=time_ms,d1=A", n=2, form="columns")


def test_wrench_columns_with_units_from_names_or_given():
    text = "t_s,Fx_N,Fy_N,Mz_Nm\n0,0.5,-0.25,0.01\n0.1,0,0,0\n"
    w = read_command_log(text, parse_column_map("t=t_s,fx=Fx_N,fy=Fy_N,mz=Mz_Nm", command_keys(0)),
                         n_valves=None, what="w.csv")
    assert w.kind == "wrench"
    np.testing.assert_allclose(w.values[0], [0.5, -0.25, 0.01])
    text = "t_s,fx,fy,mz\n0,500,-250,10\n0.1,0,0,0\n"
    cols = parse_column_map("t=t_s,fx=fx,fy=fy,mz=mz", command_keys(0))
    with pytest.raises(UserError, match=r"the force unit of column 'fx', 'fy' is not stated"):
        read_command_log(text, cols, n_valves=None, what="w.csv")
    w = read_command_log(text, cols, n_valves=None, units=("mN", "mNm"), what="w.csv")
    np.testing.assert_allclose(w.values[0], [0.5, -0.25, 0.01])


def test_nothing_but_a_vector_is_guessed():
    with pytest.raises(UserError, match=r"say how to read the valves column: --as vector\|bitmask"):
        _read(THR, "t=t_s,valves=bitmask")
    with pytest.raises(UserError, match=r"say how to read per-valve columns"):
        _read("t_s,A\n0,1\n1,0\n", "t=t_s,d1=A", n=1)


@pytest.mark.parametrize("text, cols, kw, message", [
    ("t_s,v\n0,\"[1, 0]\"\n", "t=t_s,valves=v", {}, r"one command time only"),
    ("t_s,v\n1,\"[1, 0]\"\n0,\"[1, 0]\"\n", "t=t_s,valves=v", {}, r"time goes back at data row 2"),
    ("t_s,v\n0,\"[1, 0]\"\nx,\"[1, 0]\"\n", "t=t_s,valves=v", {}, r"line 3, column 1 \(t_s\): 'x' is not a number"),
    ("t_s,v\n0,\"[1, 0]\"\n1\n", "t=t_s,valves=v", {}, r"line 3 has 1 cells; column 'v' is missing"),
    ("t_s,v\n", "t=t_s,valves=v", {}, r"no data rows"),
    ("t_s,v\n0,\"[1, 0]\"\n1,\"[1, 0]\"\n", "t=t_s,valves=w", {}, r"no column 'w' \(for valves\)"),
    ("tick,v\n0,\"[1, 0]\"\n1,\"[1, 0]\"\n", "t=tick,valves=v", {}, r"time unit of column 'tick' is not stated"),
    ("t_s,v\n0,\"[1, 0]\"\n1,\"[1, 0]\"\n", "valves=v", {}, r"give the time column"),
])
def test_damaged_logs_are_one_line(text, cols, kw, message):
    with pytest.raises(UserError, match=message):
        _read(text, cols, n=2, **kw)


def test_repeated_times_keep_the_later_row_and_the_origin_keeps_the_state_in_force():
    text = "t_s,v\n0,\"[1, 0]\"\n1,\"[0, 1]\"\n1,\"[1, 1]\"\n2,\"[0, 0]\"\n"
    c = _read(text, "t=t_s,valves=v", n=2)
    assert c.counts["repeated"] == 1
    np.testing.assert_array_equal(c.values[1], [100, 100])
    t, v, dropped = shift_to_origin(c, 1.5)
    np.testing.assert_allclose(t, [0.0, 0.5, 1.5])
    np.testing.assert_array_equal(v[0], [100, 100])
    assert dropped == 1
    with pytest.raises(UserError, match="do not overlap"):
        shift_to_origin(c, 10.0)
