"""A wrench input (docs/run-format.md "Wrench runs"): testbeds that log the
realised force and torque instead of valve commands write ``wrench.csv`` ``t,fx,fy,mz``
(N, N, N m about the tracked origin; a zero-order hold, the last row marks the end) with
the frame in run.json ``"wrench_frame"``: ``"body"`` (default) or ``"lab"``.

The plant takes the four virtual thrusts of one module at the tracked origin; a body-frame
wrench maps onto them exactly (:func:`common.layout.virtual_from_wrench`). A lab-frame
force turns with the body: it is rotated into the body frame by the MEASURED yaw (the
poses' psi, unwrapped and interpolated linearly), the hold split at every pose time inside
its span so each piece takes the yaw at its midpoint. Two errors remain, both stated: the
yaw's change inside one pose interval (second order: the midpoint rule), and the yaw's
measurement noise, which turns each piece's force by a zero-mean angle of sigma_yaw (a
perpendicular force error of ``|F| sigma_yaw`` per pose interval, independent between
intervals, that the fit does not count as noise). The moment mz is the same in both frames.
"""

from __future__ import annotations

import numpy as np

from common.errors import UserError
from common.layout import virtual_from_wrench

WRENCH_COLUMNS = ("t", "fx", "fy", "mz")
WRENCH_FRAMES = ("body", "lab")


def wrench_frame(meta: dict, where: str) -> str:
    """run.json's ``wrench_frame`` (default ``body``); UserError naming ``where`` else."""
    frame = meta.get("wrench_frame", "body")
    if frame not in WRENCH_FRAMES:
        raise UserError(f"{where}: wrench_frame must be \"body\" or \"lab\", got {frame!r}")
    return frame


def body_wrench(t: np.ndarray, wrench: np.ndarray, frame: str, pose_t: np.ndarray,
                psi_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The hold ``(t, wrench (N, 3))`` in the body frame: as given for ``body``; for
    ``lab`` split at the pose times and rotated by the measured yaw (module doc)."""
    t = np.asarray(t, dtype=float)
    wrench = np.asarray(wrench, dtype=float)
    if frame == "body":
        return t, wrench
    inside = pose_t[(pose_t > t[0]) & (pose_t < t[-1])]
    tt = np.union1d(t, inside)
    rows = np.searchsorted(t, tt, side="right") - 1
    w = wrench[np.minimum(rows, len(t) - 1)].copy()
    mid = np.append(0.5 * (tt[:-1] + tt[1:]), tt[-1])
    psi = np.interp(mid, pose_t, np.unwrap(psi_rad))
    c, s = np.cos(psi), np.sin(psi)
    fx, fy = w[:, 0].copy(), w[:, 1].copy()
    w[:, 0] = c * fx + s * fy
    w[:, 1] = -s * fx + c * fy
    return tt, w


def wrench_thrusts(t: np.ndarray, wrench: np.ndarray, frame: str, pose_t: np.ndarray,
                   psi_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(times, virtual thrusts (N, 4))`` of a wrench input: what the plant takes."""
    tt, w = body_wrench(t, wrench, frame, pose_t, psi_rad)
    return tt, virtual_from_wrench(w)
