"""What the motion capture sees of the plant: the tracked frame's pose and its Jacobian.

The plant's state is the centre of mass's (:mod:`estimator.plant.model`); the tracked
frame sits at the body-frame offset ``c = (cx, cy)`` (m) from it, so its pose is
``p = p_com - R(psi) c``. Arrays broadcast over leading dimensions.
"""

from __future__ import annotations

import numpy as np


def tracked_pose(states, cx=0.0, cy=0.0):
    """Pose ``(x, y, psi)`` (..., 3) of the tracked frame from centre-of-mass states (..., 6):
    ``p = p_com - R(psi) c``. Without an offset, the first three states exactly."""
    states = np.asarray(states, dtype=float)
    out = states[..., :3].copy()
    if cx != 0.0 or cy != 0.0:
        c, sn = np.cos(states[..., 2]), np.sin(states[..., 2])
        out[..., 0] -= c * cx - sn * cy
        out[..., 1] -= sn * cx + c * cy
    return out


def com_from_tracked(pose, cx=0.0, cy=0.0):
    """The centre of mass's ``(x, y, psi)`` from a tracked pose (..., 3): ``p + R(psi) c``."""
    pose = np.asarray(pose, dtype=float)
    out = pose.copy()
    if cx != 0.0 or cy != 0.0:
        c, sn = np.cos(pose[..., 2]), np.sin(pose[..., 2])
        out[..., 0] += c * cx - sn * cy
        out[..., 1] += sn * cx + c * cy
    return out


def output_jacobian(states, phi, names, cx=0.0, cy=0.0):
    """``d tracked pose(t_k) / d z0`` (N, 3, 6+p) from the transition matrices' state rows
    ``phi`` (N, 6, 6+p): ``[I_3 0] Phi`` plus the offset's terms (the yaw column rotates c;
    columns cx, cy of ``names`` move the tracked point). Without an offset and with cx, cy
    not estimated, ``phi[:, :3, :]`` exactly."""
    names = tuple(names)
    est = [n for n in ("cx", "cy") if n in names]
    if not est and cx == 0.0 and cy == 0.0:
        return phi[:, :3, :]
    H = phi[:, :3, :].copy()
    psi = np.asarray(states, float)[:, 2]
    c, sn = np.cos(psi), np.sin(psi)
    dx_dpsi = sn * cx + c * cy      # d(-R c)/dpsi, x row
    dy_dpsi = -c * cx + sn * cy     # y row
    H[:, 0, :] += dx_dpsi[:, None] * phi[:, 2, :]
    H[:, 1, :] += dy_dpsi[:, None] * phi[:, 2, :]
    if "cx" in names:
        j = 6 + names.index("cx")
        H[:, 0, j] -= c
        H[:, 1, j] -= sn
    if "cy" in names:
        j = 6 + names.index("cy")
        H[:, 0, j] += sn
        H[:, 1, j] -= c
    return H
