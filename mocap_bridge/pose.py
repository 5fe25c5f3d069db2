"""Pose samples, Euler/quaternion/yaw maths and axis mapping.

Pure functions, no I/O. A :class:`PoseSample` is what every source yields; the bridge
maps it to the table frame (:class:`AxisMap`), computes the planar yaw and encodes it
with :func:`encode_pose`. Consumers (recorder, live estimator) decode with
:func:`decode_pose`. The payload format (schema ``tpods.pose/1``) lives in
:mod:`common.wire`; its names are re-exported here as the bridge's public API.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

from common.wire import (  # noqa: F401  (re-exported: the bridge's payload API)
    ENCODING,
    POSE_FIELDS,
    SCHEMA,
    STATS_SCHEMA,
    decode_pose,
    encode_pose,
    pose_key,
    sanitize_chunk,
)


class PoseSample(NamedTuple):
    """One rigid-body pose as a source delivers it (mocap lab frame, SI units).

    ``x, y, z`` in metres, ``(qx, qy, qz, qw)`` a unit quaternion (body to lab).
    ``t`` is the capture time on the host clock (s, ``time.time()`` scale), ``t_recv``
    the host receive time. When ``occluded`` the pose fields are ignored (may be NaN).
    ``t_src`` is the time on the source's own timeline (replay/sim), else None.
    """

    body: str
    frame: int
    t: float
    t_recv: float
    x: float
    y: float
    z: float
    qx: float
    qy: float
    qz: float
    qw: float
    occluded: bool = False
    t_src: float | None = None


def occluded_sample(body: str, frame: int, t: float, t_recv: float,
                    t_src: float | None = None) -> PoseSample:
    nan = math.nan
    return PoseSample(body, frame, t, t_recv, nan, nan, nan, nan, nan, nan, nan, True, t_src)


# ------------------------------------------------------------------ rotations


def euler_xyz_to_quat(rx: float, ry: float, rz: float) -> tuple[float, float, float, float]:
    """Vicon Euler XYZ angles (rad) to a quaternion ``(qx, qy, qz, qw)``.

    Vicon's convention: ``R = Rx(rx) @ Ry(ry) @ Rz(rz)`` (intrinsic X, then Y', then Z'';
    the SDK recovers ``ry = asin(R[0, 2])``). Same as scipy ``from_euler('XYZ', ...)``.
    """
    cx, sx = math.cos(0.5 * rx), math.sin(0.5 * rx)
    cy, sy = math.cos(0.5 * ry), math.sin(0.5 * ry)
    cz, sz = math.cos(0.5 * rz), math.sin(0.5 * rz)
    # q = qx * qy * qz (Hamilton product, vector first)
    return (
        sx * cy * cz + cx * sy * sz,
        cx * sy * cz - sx * cy * sz,
        cx * cy * sz + sx * sy * cz,
        cx * cy * cz - sx * sy * sz,
    )


def quat_mul(a: tuple[float, ...], b: tuple[float, ...]) -> tuple[float, float, float, float]:
    """Hamilton product ``a * b`` of quaternions given as ``(x, y, z, w)``."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    )


def wrap_pi(a: float) -> float:
    """Wrap an angle to (-pi, pi]."""
    w = math.remainder(a, 2.0 * math.pi)
    return math.pi if w <= -math.pi else w


def yaw_heading(qx: float, qy: float, qz: float, qw: float) -> float:
    """Heading of the body x axis projected onto the table plane (rad, (-pi, pi])."""
    y = 2.0 * (qx * qy + qw * qz)
    x = 1.0 - 2.0 * (qy * qy + qz * qz)
    a = math.atan2(y, x)
    return math.pi if a == -math.pi else a


def yaw_twist(qx: float, qy: float, qz: float, qw: float) -> float:
    """Twist angle about the table normal (swing-twist decomposition), rad, (-pi, pi]."""
    return wrap_pi(2.0 * math.atan2(qz, qw))


def yaw_quat(psi: float) -> tuple[float, float, float, float]:
    """Quaternion of a pure rotation ``psi`` (rad) about the table normal."""
    return (0.0, 0.0, math.sin(0.5 * psi), math.cos(0.5 * psi))


_UP_ROT = {
    # table frame from mocap frame: p_table = M p_lab, q_table = q_M * q_lab
    "z": None,                                           # Z-up: identity
    "y": (math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)),     # Y-up: M = Rx(+90 deg), (x, y, z) -> (x, -z, y)
}


@dataclass(frozen=True)
class AxisMap:
    """Mocap lab frame to table frame, and the planar projection.

    Attributes:
        up: the mocap axis along the table normal: ``"z"`` (Vicon default, identity)
            or ``"y"`` (Y-up set-ups: table x = lab X, table y = -lab Z, normal = lab Y).
        projection: how yaw is taken from the 3-D orientation: ``"heading"`` (angle of
            the body x axis projected onto the table plane) or ``"twist"`` (rotation
            about the normal from the swing-twist decomposition). Equal when the body
            is level.
        yaw_offset_rad: added to the yaw (e.g. the body's marker-frame mounting).
        origin_m: table-frame point subtracted from positions, metres.
    """

    up: str = "z"
    projection: str = "heading"
    yaw_offset_rad: float = 0.0
    origin_m: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if self.up not in _UP_ROT:
            raise ValueError(f"up axis must be 'z' or 'y', got {self.up!r}")
        if self.projection not in ("heading", "twist"):
            raise ValueError(f"projection must be 'heading' or 'twist', got {self.projection!r}")

    @property
    def is_identity(self) -> bool:
        return self.up == "z" and self.origin_m == (0.0, 0.0, 0.0)

    def apply(self, s: PoseSample) -> tuple[float, float, float, float, float, float, float, float]:
        """Table-frame ``(x, y, z, qx, qy, qz, qw, yaw)`` of a non-occluded sample."""
        x, y, z = s.x, s.y, s.z
        q = (s.qx, s.qy, s.qz, s.qw)
        if self.up == "y":
            x, y, z = x, -z, y
            q = quat_mul(_UP_ROT["y"], q)
        ox, oy, oz = self.origin_m
        x, y, z = x - ox, y - oy, z - oz
        yaw = (yaw_heading if self.projection == "heading" else yaw_twist)(*q)
        if self.yaw_offset_rad:
            yaw = wrap_pi(yaw + self.yaw_offset_rad)
        return (x, y, z, q[0], q[1], q[2], q[3], yaw)
