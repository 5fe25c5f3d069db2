"""A swing log in the wrong unit, caught before the fit: the dominant period of the trace and,
for a gyro's rates, the amplitude they imply, against what a hung body can do. The message
names the option that fixes it (a rate in deg/s read as rad/s swings 57 times too far; a
time in ms read as s makes the period 1000 times too long)."""

from __future__ import annotations

import math

import numpy as np

PERIOD_RANGE_S = (0.1, 120.0)
"""A bifilar, trifilar or compound pendulum swings with a period in this range."""
AMPLITUDE_LIMIT_DEG = 90.0
"""Beyond this the strings wind over each other: no model holds (and no lab swings so far)."""


def dominant_period_s(t: np.ndarray, y: np.ndarray) -> float | None:
    """The period of the largest spectral peak of ``y`` (resampled evenly), or None."""
    t = np.asarray(t, float)
    y = np.asarray(y, float) - np.mean(y)
    if len(t) < 8 or not t[-1] > t[0]:
        return None
    n = len(t)
    grid = np.linspace(t[0], t[-1], n)
    yy = np.interp(grid, t, y) * np.hanning(n)
    spec = np.abs(np.fft.rfft(yy))
    f = np.fft.rfftfreq(n, (t[-1] - t[0]) / (n - 1))
    if len(spec) < 3:
        return None
    k = int(np.argmax(spec[1:])) + 1
    return 1.0 / f[k] if f[k] > 0 else None


PEAK_OVER_MEDIAN = 10.0
"""A swing's spectral peak stands this far above the spectrum's median (magnitudes); white
noise's largest peak stands 3-4 times above it."""


def swing_presence_problem(t: np.ndarray, y: np.ndarray) -> str | None:
    """One line when the trace holds no swing (its largest spectral peak is not above the
    noise), or None."""
    t = np.asarray(t, float)
    y = np.asarray(y, float) - np.mean(y)
    n = len(t)
    if n < 16 or not t[-1] > t[0]:
        return None
    grid = np.linspace(t[0], t[-1], n)
    yy = np.interp(grid, t, y)
    yy = yy - np.polyval(np.polyfit(grid, yy, 1), grid)  # a drift is no swing
    spec = np.abs(np.fft.rfft(yy * np.hanning(n)))[1:]
    med = float(np.median(spec))
    if med <= 0:
        return None
    ratio = float(spec.max()) / med
    if ratio >= PEAK_OVER_MEDIAN:
        return None
    return (f"the trace does not oscillate (no swing in the trace): its largest spectral peak "
            f"is only {ratio:.1f} times the "
            f"median of its spectrum (a swing stands far above it; at least {PEAK_OVER_MEDIAN:g}): "
            "a log of noise, of the body at rest, or of another channel")


def swing_units_problem(t: np.ndarray, y: np.ndarray, signal: str) -> str | None:
    """One line naming the option that fixes a unit mistake, or None. ``signal``: "rate"
    (rad/s), "angle" (rad) or "signal" (any unit: the period only)."""
    period = dominant_period_s(t, y)
    if period is None:
        return None
    lo, hi = PERIOD_RANGE_S
    if not lo <= period <= hi:
        hint = (" (times in ms read as s? --time-unit ms)" if period > hi
                else " (times in s read as ms? --time-unit s)")
        return (f"the trace swings with a period of {period:.4g} s, outside the {lo:g}-{hi:g} s "
                f"a hung body swings with{hint}")
    if signal in ("rate", "angle"):
        peak = float(np.percentile(np.abs(np.asarray(y) - np.median(y)), 99))
        amp = peak * period / (2 * math.pi) if signal == "rate" else peak
        amp_deg = math.degrees(amp)
        if amp_deg > AMPLITUDE_LIMIT_DEG:
            hint = (f" (rates in deg/s read as rad/s? --rate-unit deg/s: {amp_deg / 57.2958:.3g} "
                    "deg)" if signal == "rate" else " (degrees read as radians?)")
            return (f"the {'rates imply' if signal == 'rate' else 'angles show'} a swing of "
                    f"{amp_deg:.4g} deg, beyond the {AMPLITUDE_LIMIT_DEG:g} deg a suspension "
                    f"holds{hint}")
    return None
