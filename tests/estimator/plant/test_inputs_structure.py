"""Inputs for structures (issue 18): 4N channels."""

import math

import numpy as np
import pytest

from common.errors import UserError
from common.runfolder import write_run
from estimator.plant.inputs import make_input


def test_phase_sine_phases_continue_across_modules():
    t, d = make_input("phase-sine", 10.0, 50.0, 20.0, 1.0, n_channels=8)
    assert d.shape == (len(t), 8)
    i = 7
    np.testing.assert_allclose(d[:-1, i], 50 + 20 * np.sin(t[:-1] + i * math.pi / 4))
    t4, d4 = make_input("phase-sine", 10.0, 50.0, 20.0, 1.0)
    np.testing.assert_array_equal(d4, d[:, :4])  # module 1 is today's input


def test_file_input_needs_4n_columns_and_translate_rotate_is_refused(tmp_path):
    write_run(tmp_path / "r", cmd_t=np.array([0.0, 1.0, 2.0]), duty_pct=np.full((3, 8), 50.0),
              pose_t=np.array([0.0, 1.0]), pose=np.zeros((2, 3)))
    t, d = make_input(str(tmp_path / "r"), None, n_channels=8)
    assert d.shape == (3, 8)
    with pytest.raises(UserError, match=r"missing column\(s\) d9"):
        make_input(str(tmp_path / "r"), None, n_channels=12)
    with pytest.raises(UserError, match="single module's input"):
        make_input("translate-rotate", 10.0, n_channels=8)
