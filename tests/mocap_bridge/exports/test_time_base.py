"""Pose times rebuilt from logged finite-difference velocities or an interval column, and the
spread of intervals (common.interval_jitter)."""

import numpy as np
import pytest

from common.interval_jitter import interval_jitter, jitter_warning
from mocap_bridge.exports.time_base import (
    DETERMINED,
    DISAGREE,
    MISSING,
    REJECTED,
    REST,
    intervals_from_column,
    intervals_from_velocities,
    map_times,
    rebuilt_times,
    summary,
    times_from,
)


def _logged(n=201, seed=1):
    """Positions of a 15.6 ms clock's intervals and their finite-difference velocities."""
    rng = np.random.default_rng(seed)
    dt = rng.choice([3 / 64, 4 / 64, 5 / 64], n - 1)
    t = np.concatenate([[0.0], np.cumsum(dt)])
    x = 0.1 * t + 0.05 * np.sin(t)
    y = 0.03 * t
    yaw = np.angle(np.exp(1j * (3.0 + 0.4 * t)))  # wraps across +-pi
    pos = np.column_stack([x, y, yaw])
    pos[100:120] = pos[100]  # at rest: nothing determines those intervals
    d = np.diff(pos, axis=0)
    d[:, 2] = np.angle(np.exp(1j * d[:, 2]))
    vel = np.zeros_like(pos)
    vel[1:] = d / dt[:, None]
    return t, dt, pos, vel


def test_known_intervals_back_with_rest_nan_cells_and_yaw_wrap():
    t, dt, pos, vel = _logged()
    vel[50] = np.nan  # every velocity cell of a row empty: its interval is missing
    pos[150, 0] = np.nan  # x empty: y and yaw still give intervals 149 and 150
    iv = intervals_from_velocities(pos, vel)
    ok = iv.status == DETERMINED
    np.testing.assert_allclose(iv.dt[ok], dt[ok], rtol=1e-12)
    assert (iv.status == REST).sum() == 19 and (iv.status[100:119] == REST).all()
    assert iv.status[49] == MISSING and ok[149] and ok[150]
    assert iv.counts() == {"determined": 180, "at_rest": 19, "missing": 1, "disagree": 0, "rejected": 0}
    np.testing.assert_allclose(iv.dt[~ok], np.median(dt[ok]))
    tt = times_from(np.arange(len(t)) * 0.06 + 5.0, iv)
    assert tt[0] == 5.0 and len(tt) == len(t) and (np.diff(tt) > 0).all()


def test_yaw_alone_across_the_wrap():
    t, dt, pos, vel = _logged()
    pos[:, :2] = vel[:, :2] = np.nan  # only yaw logged
    wraps = np.abs(np.diff(pos[:, 2])) > np.pi
    assert wraps.any()
    iv = intervals_from_velocities(pos, vel)
    assert (iv.status[wraps] == DETERMINED).all()
    np.testing.assert_allclose(iv.dt[iv.status == DETERMINED], dt[iv.status == DETERMINED], rtol=1e-12)


def test_rebuilt_times_keeps_its_signature():
    t, dt, pos, vel = _logged()
    tt = rebuilt_times(np.arange(len(t)) * 0.06, pos, vel)
    assert tt[-1] > 0.06 * (len(t) - 1)  # the 62.5 ms median interval beats the nominal 60


def test_velocities_that_are_not_finite_differences_disagree_and_are_filled():
    t, dt, pos, vel = _logged()
    vel[10:20] *= np.linspace(0.8, 1.2, 10)[:, None, None][:, 0] * np.array([1.0, 1.1, 0.9])
    iv = intervals_from_velocities(pos, vel)
    assert (iv.status[9:19] == DISAGREE).all()
    assert iv.dt[9] == iv.fill_s


def test_resolution_of_the_cells_decides_what_resolves():
    t, dt, pos, vel = _logged()
    q = 1e-5  # positions and velocities written to 5 decimals
    iv = intervals_from_velocities(np.round(pos, 5), np.round(vel, 5), np.full_like(pos, q), np.full_like(vel, q))
    ok = iv.status == DETERMINED
    assert ok.sum() == 181 and (iv.status == REST).sum() == 19
    assert np.abs(iv.dt[ok] / dt[ok] - 1).max() < 2e-3  # within the bound the resolution gives
    coarse = np.full_like(pos, 1e-2)  # to 1 cm and 0.01 m/s: hardly any interval resolves
    iv = intervals_from_velocities(np.round(pos, 2), np.round(vel, 2), coarse, coarse)
    ok = iv.status == DETERMINED
    assert ok.sum() <= 5 and np.abs(iv.dt[ok] / dt[ok] - 1).max() < 0.02


def test_non_positive_interval_rejected_and_no_motion_refused():
    t, dt, pos, vel = _logged()
    vel[30] = -vel[30]  # every component gives a negative interval
    iv = intervals_from_velocities(pos, vel)
    assert iv.status[29] == REJECTED and iv.dt[29] > 0
    with pytest.raises(ValueError, match="never moves"):
        intervals_from_velocities(np.zeros((5, 3)), np.zeros((5, 3)))


def test_interval_column():
    iv = intervals_from_column(np.array([np.nan, 0.05, 0.07, np.nan, -0.01, 0.06]))
    assert iv.status.tolist() == [DETERMINED, DETERMINED, MISSING, REJECTED, DETERMINED]
    np.testing.assert_allclose(iv.dt, [0.05, 0.07, 0.06, 0.06, 0.06])
    with pytest.raises(ValueError):
        intervals_from_column(np.array([0.0, 0.0, -1.0]))


def test_map_times_exact_at_the_knots_and_extrapolated_at_the_rate():
    kn = np.array([0.0, 0.06, 0.12, 0.18])
    kr = np.array([0.0, 0.0625, 0.125, 0.1875])
    out, outside = map_times(np.array([-0.06, 0.06, 0.09, 0.24]), kn, kr)
    np.testing.assert_allclose(out, [-0.0625, 0.0625, 0.09375, 0.25])
    assert outside == 2 and out[1] == kr[1]


def test_summary_spans_and_rate():
    t, dt, pos, vel = _logged()
    nominal = np.arange(len(t)) * 0.06
    iv = intervals_from_velocities(pos, vel)
    s = summary(nominal, times_from(nominal, iv), iv, "Control_Time")
    assert s["nominal_span_s"] == pytest.approx(12.0)
    assert s["rate_difference"] == pytest.approx(s["rebuilt_span_s"] / 12.0 - 1)
    assert s["filled"] == {"at_rest": 19} and s["determined"] == 181


def test_interval_jitter():
    steady = interval_jitter(np.arange(100) / 120.0)
    assert not steady["large"] and steady["spread"] == pytest.approx(1.0)
    assert jitter_warning(steady) is None
    t, *_ = _logged()
    j = interval_jitter(t)
    assert j["large"] and j["spread"] == pytest.approx(5 / 3)
    assert "p95/p5 1.67" in jitter_warning(j)
    assert not interval_jitter(np.array([0.0]))["large"]


def test_off_grid_span_tells_jitter_from_dropped_frames():
    from common.interval_jitter import off_grid_span

    rng = np.random.default_rng(3)
    steady = np.cumsum(np.where(rng.random(500) < 0.1, 2, 1) / 120.0)  # 10 % frames dropped
    assert off_grid_span(steady) < 1e-9
    coarse = np.cumsum(rng.choice([3, 4, 5], 500) / 64.0)  # a 1/64 s clock's intervals
    assert off_grid_span(coarse) > 0.4
