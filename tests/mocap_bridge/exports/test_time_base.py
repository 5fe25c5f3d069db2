"""Pose times rebuilt from logged finite-difference velocities."""

import numpy as np
import pytest

from mocap_bridge.exports.time_base import intervals_from_velocities, rebuilt_times


def test_known_intervals_back_with_rest_and_yaw_wrap():
    rng = np.random.default_rng(1)
    dt = rng.choice([3 / 64, 4 / 64, 5 / 64], 200)  # a 15.6 ms clock's intervals
    t = np.concatenate([[0.0], np.cumsum(dt)])
    x = 0.1 * t + 0.05 * np.sin(t)
    x[100:120] = x[100]  # at rest: nothing determines those intervals
    y = np.where(np.arange(len(t)) >= 100, 0.0, 0.03 * t)
    y[100:] = y[99]
    yaw = np.angle(np.exp(1j * (3.0 + 0.4 * t)))  # wraps across +-pi
    yaw[100:120] = yaw[100]
    pos = np.column_stack([x, y, yaw])
    vel = np.zeros_like(pos)
    d = np.diff(pos, axis=0)
    d[:, 2] = np.angle(np.exp(1j * d[:, 2]))
    vel[1:] = d / dt[:, None]
    got, ok = intervals_from_velocities(pos, vel)
    assert np.allclose(got[ok], dt[ok], rtol=1e-12)
    assert (~ok).sum() == 19  # the 19 intervals at rest take the median
    assert np.allclose(got[~ok], np.median(dt[ok]))
    tt = rebuilt_times(np.arange(len(t)) * 0.06 + 5.0, pos, vel)
    assert tt[0] == 5.0 and len(tt) == len(t)


def test_no_motion_refused():
    with pytest.raises(ValueError, match="never moves"):
        intervals_from_velocities(np.zeros((5, 3)), np.zeros((5, 3)))
