"""Stretches of a run where the model cannot hold, found and named so the fit leaves them out.

- **at rest with the valves closed** (:func:`find_events`): the body stays still (speed below
  :data:`REST_SPEED_M_S`, yaw rate below :data:`REST_RATE_RAD_S`) for at least
  :data:`REST_MIN_S` while no valve is commanded open: parked on the table or held. A floating
  body on a real table drifts (tilt); one that does not is touching something, and a
  stretch with no force and no motion informs nothing anyway.
- **a residual burst** (:func:`outlier_segments`): a segment whose residual rms is more than
  :data:`BURST_FACTOR` times the median segment's and above the stated noise: a hand on
  the vehicle, a contact, a tether pulling, a tracking glitch.
"""

from __future__ import annotations

import numpy as np

REST_SPEED_M_S = 0.002
REST_RATE_RAD_S = np.radians(0.2)
REST_MIN_S = 2.0
BURST_FACTOR = 5.0


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """``[start, stop)`` index ranges of the True runs of ``mask``."""
    m = np.concatenate([[False], mask, [False]]).astype(int)
    d = np.diff(m)
    return list(zip(np.nonzero(d == 1)[0], np.nonzero(d == -1)[0], strict=True))


def find_events(pose_t: np.ndarray, pose: np.ndarray, cmd_t: np.ndarray,
                duty_pct: np.ndarray) -> list[tuple[float, float, str]]:
    """``(t0, t1, why)`` of every stretch at rest with the valves closed (module doc)."""
    t = np.asarray(pose_t, float)
    if len(t) < 5:
        return []
    # velocities over a 0.5 s window: the noise of one interval would hide rest
    w = max(1, int(round(0.5 / max(float(np.median(np.diff(t))), 1e-6))))
    i0 = np.clip(np.arange(len(t)) - w, 0, len(t) - 1)
    i1 = np.clip(np.arange(len(t)) + w, 0, len(t) - 1)
    dt = np.maximum(t[i1] - t[i0], 1e-9)
    speed = np.hypot(pose[i1, 0] - pose[i0, 0], pose[i1, 1] - pose[i0, 1]) / dt
    rate = np.abs(np.angle(np.exp(1j * (pose[i1, 2] - pose[i0, 2])))) / dt
    if len(cmd_t):
        row = np.clip(np.searchsorted(cmd_t, t, side="right") - 1, 0, len(cmd_t) - 1)
        closed = ~np.any(np.asarray(duty_pct)[row] > 0, axis=1) | (t < cmd_t[0])
    else:
        closed = np.ones(len(t), bool)
    still = (speed < REST_SPEED_M_S) & (rate < REST_RATE_RAD_S) & closed
    out = []
    for a, b in _runs(still):
        if t[b - 1] - t[a] >= REST_MIN_S:
            out.append((float(t[a]), float(t[b - 1]),
                        "at rest with every valve closed (parked or held: no force, no motion)"))
    return out


def outlier_segments(prob, lm) -> list[tuple[float, float, str]]:
    """``(t0, t1, why)`` of the segments whose residuals burst (module doc)."""
    r = lm.r.reshape(-1, 3)
    seg = prob.seg
    n = np.bincount(seg, minlength=prob.n_seg)
    rms = np.sqrt(np.bincount(seg, np.sum(r ** 2, 1), prob.n_seg) / np.maximum(3 * n, 1))
    if prob.n_seg < 4:
        return []
    med = float(np.median(rms))
    out = []
    for s in np.nonzero((rms > BURST_FACTOR * med) & (rms > 1.0))[0]:
        a, b = prob.plan.bounds[s]
        out.append((float(prob.pose_t[a]), float(prob.pose_t[b - 1]),
                    f"residual burst: rms {rms[s]:.1f}x the stated noise, {rms[s] / med:.0f}x the "
                    "median segment's (a contact, a hand, a tether or a tracking glitch)"))
    return out
