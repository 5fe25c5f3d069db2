"""What a filter run says about itself: information, residuals, the poses' scatter.

:func:`filter_plausibility` tells whether each parameter learnt from the run (thrust, net
force, torque, the sigma's shrinkage) and whether the post-update residuals match the stated
pose noise (:func:`residual_rms`; for a filter that blew up, the poses' own scatter,
:func:`pose_scatter`), as batch least squares reports it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from estimator.filters.config import NZ
from estimator.filters.kernels import TWO_PI

INFO_FRACTION = 0.5
"""A parameter whose final sigma is above this fraction of its initial sigma has learnt
(almost) nothing from the run: the estimate is mostly the starting guess, and the fit is
not called converged."""


def residual_rms(t, x, updated, pose, tail: float = 0.5) -> np.ndarray:
    """(3,) RMS of the post-update pose residuals (x, y m; yaw rad, wrapped) over the last
    ``tail`` of the updated poses (after the start-up transient)."""
    idx = np.flatnonzero(np.asarray(updated, bool))
    if len(idx) == 0:
        return np.full(3, math.nan)
    idx = idx[int(len(idx) * (1.0 - tail)):]
    d = np.asarray(pose, float)[idx] - np.asarray(x, float)[idx, :NZ]
    d[:, 2] = (d[:, 2] + math.pi) % TWO_PI - math.pi
    return np.sqrt(np.mean(d**2, axis=0))


def pose_scatter(t, pose) -> np.ndarray:
    """(3,) the poses' own noise level (x, y m; yaw rad): RMS of second differences of
    evenly spaced triples over sqrt(6) (white noise; motion adds ~a dt^2, negligible at
    mocap rates). NaN without such triples."""
    t = np.asarray(t, float)
    p = np.asarray(pose, float).copy()
    p[:, 2] = np.unwrap(p[:, 2])
    if len(t) < 3:
        return np.full(3, math.nan)
    h1, h2 = np.diff(t)[:-1], np.diff(t)[1:]
    even = np.abs(h2 - h1) <= 1e-6 * np.maximum(h1, h2)
    if not even.any():
        return np.full(3, math.nan)
    d2 = (p[2:] - 2.0 * p[1:-1] + p[:-2])[even]
    return np.sqrt(np.mean(d2**2, axis=0) / 6.0)


def filter_plausibility(t, x, sigma, updated, pose, sigma_meas, sigma0, seg_w,
                        names: Sequence[str] = ("mass", "izz"), first: int = 6
                        ) -> tuple[str, list[str], np.ndarray]:
    """What a filter's result says about itself, as batch least squares reports it.

    Args:
        t, x, sigma, updated: the filter's history (N,), (N, n), (N, n), (N,).
        pose: (N, 3) the measured poses. sigma_meas: (3,) the stated pose noise.
        sigma0: (n,) initial standard deviations. seg_w: per pose interval, the body
            wrenches (Fx, Fy, Mz) of its hold segments (:class:`Schedule`).
        names, first: the parameters and the state index of the first one.

    Returns:
        ``(no_info, warnings, rms)``: ``no_info`` is '' when every parameter learnt from
        the run, else which did not and why (no thrust, no net force, no torque, or a final
        sigma above :data:`INFO_FRACTION` of the initial one); ``warnings`` one line per
        post-update residual whose RMS is more than 10x off the stated noise, naming the
        likely causes (:func:`estimator.batch.least_squares.residual_warnings`: millimetres,
        degrees, the thrust table's unit, another body); ``rms`` the (3,) residual RMS.
        When the filter did not finish (NaN: it blew up, e.g. on poses in millimetres),
        the poses' own scatter (:func:`pose_scatter`) is compared with the stated noise
        instead.
    """
    # lazy: the batch module is needed only after a whole-run fit, not by the live filter
    from estimator.batch.least_squares import residual_warnings

    w = [wi for seg in seg_w for wi in seg]
    force = any(abs(a) > 0.0 or abs(b) > 0.0 for a, b, _ in w)
    torque = any(abs(c) > 0.0 for _, _, c in w)
    why = {}
    if not force and not torque:
        why = {n: "no thrust: every valve is closed in every command (or the thrust table "
                  "gives 0 N)" for n in names if n in ("mass", "izz")}
    else:
        if not force and "mass" in names:
            why["mass"] = "no net force (the thrusts cancel)"
        if not torque and "izz" in names:
            why["izz"] = "no torque (the commands never turn the module)"
    s0 = np.asarray(sigma0, float)
    s1 = np.asarray(sigma, float)[-1]
    for j, n in enumerate(names):
        i = first + j
        if n in why or not (s0[i] > 0 and math.isfinite(s0[i])) or not math.isfinite(s1[i]):
            continue  # (a filter that blew up is diverged, not uninformed)
        if not s1[i] <= INFO_FRACTION * s0[i]:  # NaN too
            why[n] = (f"little information: its sigma went from {s0[i]:.3g} to {s1[i]:.3g}, "
                      "the estimate is mostly the starting guess")
    no_info = ""
    if why:
        bad = list(why)
        no_info = (f"{', '.join(bad)} {'has' if len(bad) == 1 else 'have'} no information in "
                   f"this run: " + "; ".join(f"{n}: {why[n]}" for n in bad))
    rms = residual_rms(t, x, updated, pose)
    warnings = []
    if np.all(np.isfinite(rms)):
        warnings = [f"the filter's {line}" for line in
                    residual_warnings(rms, float(sigma_meas[0]), float(sigma_meas[2]))]
    else:
        sc = pose_scatter(t, pose)
        if np.all(np.isfinite(sc)):
            warnings = [f"the filter did not finish; the poses' own scatter: {line}" for line in
                        residual_warnings(sc, float(sigma_meas[0]), float(sigma_meas[2]))]
    return no_info, warnings, rms

