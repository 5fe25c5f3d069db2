"""Simulated swing recordings as other labs' sensors give them, for tests and benchmarks.

:func:`simulate_sensor_trace` integrates the large-angle model
(:func:`calibration.swing.bifilar_model.simulate_swing`) and records it as a yaw (rad, mocap),
a gyro's yaw rate (rad/s, with bias and linear drift) or a pixel track (offset, gain,
drift), adding the body's pendulum sway on its strings at sqrt(g/L) (as seen by that
sensor: a fraction of the swing's own amplitude) and white noise.
"""

from __future__ import annotations

import math

import numpy as np

from calibration.swing.bifilar_model import Pendulum, simulate_swing


def simulate_sensor_trace(p: Pendulum, signal: str, *, release_deg: float = 15.0,
                          duration_s: float = 30.0, rate_hz: float = 100.0,
                          noise: float | None = None, bias: float = 0.0, drift_per_s: float = 0.0,
                          sway_fraction: float = 0.0, gain: float = 1.0, seed: int = 0
                          ) -> tuple[np.ndarray, np.ndarray]:
    """(t s, y) of a swing released from rest at ``release_deg``.

    ``signal``: "angle" (y = bias + drift t + theta), "rate" (y = bias + drift t + th')
    or "signal" (y = bias + drift t + gain theta: pixels per rad). The sway adds
    ``sway_fraction`` times the release amplitude (its rate for "rate") at sqrt(g/L).
    Default noise: 0.5 deg (angle), 0.01 rad/s (rate), 0.5 units (signal).
    """
    rng = np.random.default_rng(seed)
    t = np.arange(int(round(duration_s * rate_hz)) + 1) / rate_hz
    th, om = simulate_swing(p, t, math.radians(release_deg))
    ws = math.sqrt(p.g / p.length_m)
    a_sway = sway_fraction * math.radians(release_deg)
    phase = rng.uniform(0, 2 * math.pi)
    if signal == "rate":
        y, sigma = om + a_sway * ws * np.cos(ws * t + phase), 0.01
    elif signal == "angle":
        y, sigma = th + a_sway * np.sin(ws * t + phase), math.radians(0.5)
    elif signal == "signal":
        y, sigma = gain * (th + a_sway * np.sin(ws * t + phase)), 0.5
    else:
        raise ValueError(f"signal must be angle, rate or signal, got {signal!r}")
    sigma = sigma if noise is None else noise
    return t, bias + drift_per_s * t + y + rng.normal(0.0, sigma, t.size)
