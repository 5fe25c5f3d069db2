"""One --window syntax for every command: T0:T1 (documented), T0,T1 read the same."""

import argparse

import pytest

from common.argtypes import parse_time_window, time_window
from common.errors import UserError
from estimator.batch.least_squares import parse_window


@pytest.mark.parametrize("text,expected", [
    ("2:15", (2.0, 15.0)), ("2,15", (2.0, 15.0)), (" 2 : 15 ", (2.0, 15.0)),
    (":15", (None, 15.0)), ("2:", (2.0, None)), (",15", (None, 15.0)),
    ("", (None, None)), (None, (None, None)), ("-1.5:3e1", (-1.5, 30.0)),
])
def test_both_separators_read_the_same(text, expected):
    assert parse_time_window(text) == expected


@pytest.mark.parametrize("text,match", [
    ("10,5", "end must follow its start"), ("10:5", "end must follow its start"),
    ("5:5", "end must follow its start"), ("abc", "T0:T1"), ("1:2:3", "T0:T1"),
    ("1,2,3", "T0:T1"), ("nan:4", "T0:T1"), ("1:inf", "T0:T1"), ("2", "T0:T1"),
])
def test_bad_windows_name_the_problem(text, match):
    with pytest.raises(ValueError, match=match):
        parse_time_window(text)
    with pytest.raises(argparse.ArgumentTypeError, match=match):
        time_window(text)
    with pytest.raises(UserError, match=match):
        parse_window(text)
