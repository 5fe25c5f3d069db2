"""When the model does not fit a run, say so: the residuals of a fit
against the stated mocap noise, and their structure.

Two checks on the residuals ``r_k`` (pose minus prediction) normalised by the stated noise
(``--sigma-pos``, ``--sigma-yaw-deg``), each returning warning lines (``[]`` when the fit is
plausible) that name the likely causes and the check that tells them apart
(:data:`CAUSES`):

- *size*: an RMS more than :data:`MISFIT_RATIO` (2x, a reduced chi-square of 4) the stated
  noise, up to :data:`estimator.batch.plausibility.RESIDUAL_RATIO` (10x) above which
  :func:`~estimator.batch.plausibility.residual_warnings` names unit mistakes instead;
- *structure*: the Wald-Wolfowitz runs test on the residuals' signs, per axis. White noise
  changes sign about every other pose; a model that misses an effect leaves long runs of
  one sign (a valve dead time of 30 ms on the phase-shifted sine: z = -25 on the yaw while
  its RMS is only 1.26x the noise). Flagged when ``z < -``:data:`RUNS_Z` (4: a false alarm
  rate of 3e-5 per axis on white residuals).

A thrust factor far from 1 is the third sign of misfit; the calibration names it
(:func:`common.plausible.thruster_factor_warnings`).
"""

from __future__ import annotations

import math

import numpy as np

from common.plausible import MISFIT_CAUSES
from estimator.batch.plausibility import RESIDUAL_RATIO

MISFIT_RATIO = 2.0
"""Residual RMS over the stated noise above which the fit is reported as a misfit."""

RUNS_Z = 4.0
"""Runs-test z below ``-RUNS_Z`` on an axis: structured (not white) residuals."""

AXES = ("x", "y", "yaw")

CAUSES = MISFIT_CAUSES


def runs_z(x: np.ndarray) -> float:
    """Wald-Wolfowitz runs test on the signs of ``x``: ``(runs - mean) / sd`` (0 when the
    signs are all one or there are too few values)."""
    s = np.sign(np.asarray(x, float))
    s = s[s != 0]
    n1, n2 = int(np.sum(s > 0)), int(np.sum(s < 0))
    n = n1 + n2
    if n1 == 0 or n2 == 0 or n < 3:
        return 0.0
    runs = 1 + int(np.sum(s[1:] != s[:-1]))
    mu = 2.0 * n1 * n2 / n + 1.0
    var = (mu - 1.0) * (mu - 2.0) / (n - 1.0)
    return float((runs - mu) / math.sqrt(var)) if var > 0 else 0.0


def normalised(residuals: np.ndarray, sigma_pos_m: float, sigma_yaw_rad: float) -> np.ndarray:
    """(N, 3) residuals over the stated noise."""
    return np.asarray(residuals, float) / np.array([sigma_pos_m, sigma_pos_m, sigma_yaw_rad])


def misfit_statistics(residuals: np.ndarray, sigma_pos_m: float, sigma_yaw_rad: float
                      ) -> dict[str, dict[str, float]]:
    """``{axis: {"rms_ratio", "runs_z"}}`` of the normalised residuals."""
    r = normalised(residuals, sigma_pos_m, sigma_yaw_rad)
    rms = np.sqrt(np.mean(r**2, axis=0))
    return {a: {"rms_ratio": float(rms[i]), "runs_z": runs_z(r[:, i])} for i, a in enumerate(AXES)}


def misfit_warnings(residuals: np.ndarray, sigma_pos_m: float, sigma_yaw_rad: float, *,
                    what: str = "the fit") -> list[str]:
    """Lines for a residual RMS between :data:`MISFIT_RATIO` and ``RESIDUAL_RATIO`` times the
    stated noise, and for structured residuals (runs test), each with :data:`CAUSES`."""
    stats = misfit_statistics(residuals, sigma_pos_m, sigma_yaw_rad)
    out = []
    big = [f"{a} {s['rms_ratio']:.3g}x" for a, s in stats.items()
           if MISFIT_RATIO < s["rms_ratio"] <= RESIDUAL_RATIO]
    if big:
        out.append(f"{what} does not fit the run: residual rms {', '.join(big)} the stated "
                   f"noise (more than {MISFIT_RATIO:g}x; --sigma-pos, --sigma-yaw-deg); {CAUSES}")
    runs = [f"{a} z = {s['runs_z']:.1f}" for a, s in stats.items() if s["runs_z"] < -RUNS_Z]
    if runs:
        out.append(f"{what} leaves structured residuals: long runs of one sign (runs test "
                   f"{', '.join(runs)}; white noise gives |z| < {RUNS_Z:g}): the model misses "
                   f"an effect; {CAUSES}")
    return out


def summary(residuals: np.ndarray, sigma_pos_m: float, sigma_yaw_rad: float) -> dict[str, object]:
    """The JSON block ``misfit``: the statistics and the thresholds."""
    return {"axes": misfit_statistics(residuals, sigma_pos_m, sigma_yaw_rad),
            "rms_ratio_limit": MISFIT_RATIO, "runs_z_limit": -RUNS_Z}

