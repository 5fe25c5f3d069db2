"""The plausibility rules of :mod:`common.plausible` (issue 26), one per quantity, alone; the
commands that use them are tested in tests/tpods/cli/test_bad_input_leftovers.py."""

from __future__ import annotations

import math

import numpy as np
import pytest

from common import plausible as pl
from common.errors import UserError
from common.structure import Module, Structure
from common.thrust_table import ThrustTable
from common.thrust_uncertainty import ThrustUncertainty


def test_body_rules_keep_their_old_home_and_texts():
    from estimator.batch import least_squares as ls

    assert ls.BODY_MASS_RANGE_KG is pl.BODY_MASS_RANGE_KG and ls.smallest_gyration_m is pl.smallest_gyration_m
    assert ls.body_warnings(2.268, 3.78e-3) == []
    w = ls.body_warnings(231.0, 3.86, unit="N")
    assert w[0].startswith("mass 231 kg is outside 0.05-200 kg: implausible for an air-table body")
    assert pl.body_problems(1.0, -1.0) == ["Izz -1 kg m^2 is not positive"]
    assert "lead sphere" in pl.gyration_problem(720.0, 1.2e-3, whole_body=False)
    assert pl.gyration_problem(0.04, 0.0, whole_body=False) == ""  # a point part


def test_balance_reading_against_accuracy():
    pl.check_balance_reading(0.720, 2.5e-3)
    pl.check_balance_reading(0.001, 0.0)  # no stated accuracy: no rule
    with pytest.raises(UserError, match=r"the mean reading 2.5 g is within the balance's accuracy"):
        pl.check_balance_reading(2.5e-3, 2.5e-3)
    assert pl.balance_mass_warnings(0.72, "g") == []
    assert "'lb'" in pl.balance_mass_warnings(326.6, "lb")[0]
    assert "mass 0.01 kg is outside" in pl.balance_mass_warnings(0.01)[0]


def test_pose_rows_by_line():
    pose = np.zeros((3, 3))
    pl.check_pose_rows(pose, [2, 3, 4], "p.csv")
    pose[:, :2] = 3000.0  # millimetres on a 3 m table: left to the estimators' residual check
    pl.check_pose_rows(pose, [2, 3, 4], "p.csv")
    pose[2, 1] = -1e30
    with pytest.raises(UserError, match=r"^p.csv: line 4: y = -1e\+30 m is not a position"):
        pl.check_pose_rows(pose, [2, 3, 4], "p.csv")


def test_duty_rows_and_ranges():
    d = np.array([[0.0, 50.0], [20.0, 95.0]])
    pl.check_duty_rows(d, [2, 3], "c.csv")
    with pytest.raises(UserError, match=r"^c.csv: line 3: duty d2 = 95 % is outside the thrust table's"):
        pl.check_duty_rows(d, [2, 3], "c.csv", (10.0, 90.0))
    d[0, 0] = -1
    with pytest.raises(UserError, match=r"^c.csv: line 2: duty outside 0..100 %$"):
        pl.check_duty_rows(d, [2, 3], "c.csv")
    pl.check_duty_range(10, 90, "x")
    pl.check_duty_range(50, 50, "x")
    with pytest.raises(UserError, match=r"^x: the range 90..10 % is reversed \(LOW above HIGH\); give 10 first$"):
        pl.check_duty_range(90, 10, "x")


@pytest.mark.parametrize("t", [math.nan, math.inf, -math.inf])
def test_time_stamps_are_finite(t):
    pl.check_finite_time(None, "--t0")
    pl.check_finite_time(1.7e9, "--t0")
    with pytest.raises(UserError, match="--t0 must be a finite time"):
        pl.check_finite_time(t, "--t0")


def test_calibration_factors():
    assert pl.factor_warnings(["efficiency.1", "nozzle_scale.2"], [0.97, 1.49]) == []
    w = pl.factor_warnings(["efficiency.1", "efficiency.2"], [3.15, 0.4])
    assert len(w) == 1 and w[0].startswith("efficiency.1 = 315 %, efficiency.2 = 40 %: outside 50-150 %")


def test_module_spacing():
    Structure("ok", (Module("a", (-0.05, 0.0), 0.0), Module("b", (0.05, 0.0), 0.0)))
    with pytest.raises(UserError, match=r"modules 'a' and 'b' are 5 cm apart"):
        Structure("s", (Module("a", (0.0, 0.0), 0.0), Module("b", (0.03, 0.04), 90.0)))


def test_an_uncertainty_entry_needs_its_nozzle_row():
    t = ThrustTable.default()
    from dataclasses import replace

    replace(t, uncertainty=ThrustUncertainty(0.01, {4: 0.02}))
    with pytest.raises(UserError, match=r"^\[uncertainty.nozzles.5\]: the table has no \[nozzles.5\]"):
        replace(t, uncertainty=ThrustUncertainty(0.01, {5: 0.02}))
