"""What every pose-export parser shares: the result, units, the floor plane and yaw.

- :class:`PoseTable`: planar poses (s, m, rad) with the counts of what was skipped and a
  description of the source (format, body, units, axis mapping) for run.json.
- Units: :data:`LENGTH_M` / :data:`ANGLE_RAD` / :data:`TIME_S` (factors to SI), looked up
  by :func:`length_factor` etc., which refuse an unknown unit in one line.
- :class:`FloorPlane`: which two mocap axes (with signs) are the table's x and y
  (``"xy"`` for Z-up systems, ``"x-z"`` or ``"zx"`` for Y-up ones). The table normal is
  their cross product, so a plane is always right-handed and yaw counter-clockwise seen
  from above.
- Rotations on arrays: quaternions, Vicon Euler XYZ, helical (rotation vector) and Motive
  Euler orders to rotation matrices; :func:`plane_yaw` takes the yaw of the body's
  x axis (the mocap axis that is the table's x) in the plane.
- :func:`parse_cell`: one CSV cell to a float, NaN for an empty or "NaN" cell (occluded),
  a :class:`~common.errors.UserError` naming the line and column for anything else.

Pure functions on text and arrays; no files are opened here.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from common.errors import UserError

LENGTH_M = {"m": 1.0, "meters": 1.0, "metres": 1.0, "mm": 1e-3, "millimeters": 1e-3,
            "millimetres": 1e-3, "cm": 1e-2, "centimeters": 1e-2, "centimetres": 1e-2}
ANGLE_RAD = {"rad": 1.0, "radians": 1.0, "deg": math.pi / 180.0, "degrees": math.pi / 180.0}
TIME_S = {"s": 1.0, "seconds": 1.0, "sec": 1.0, "ms": 1e-3, "us": 1e-6}


def _factor(table: dict[str, float], unit: str, what: str) -> float:
    key = unit.strip().lower()
    if key not in table:
        known = ", ".join(k for k in table if len(k) <= 3)
        raise UserError(f"unknown {what} unit {unit!r} (known: {known})")
    return table[key]


def length_factor(unit: str) -> float:
    """Metres per ``unit`` (m, mm, cm, Meters, Millimeters, ...)."""
    return _factor(LENGTH_M, unit, "length")


def angle_factor(unit: str) -> float:
    """Radians per ``unit`` (rad, deg)."""
    return _factor(ANGLE_RAD, unit, "angle")


def time_factor(unit: str) -> float:
    """Seconds per ``unit`` (s, ms, us)."""
    return _factor(TIME_S, unit, "time")


@dataclass
class PoseTable:
    """Planar poses read from an export.

    Attributes:
        t_s: seconds from the first kept frame.
        x_m, y_m: table-frame position, metres.
        psi_rad: yaw, radians, wrapped to (-pi, pi].
        t0_source_s: the source time of the first kept frame, seconds on the source's clock
            (a command log of the same recording is shifted by it).
        counts: ``frames`` (data rows), ``kept``, ``occluded`` (empty/NaN cells),
            ``repeated`` (a time equal to the previous kept frame's).
        source: what the file was and how it was read (for run.json).
    """

    t_s: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    psi_rad: np.ndarray
    t0_source_s: float
    counts: dict[str, int] = field(default_factory=dict)
    source: dict[str, Any] = field(default_factory=dict)


_AXIS = {"x": 0, "y": 1, "z": 2}
_PLANE = re.compile(r"([+-]?)([xyz])([+-]?)([xyz])")


@dataclass(frozen=True)
class FloorPlane:
    """The table's x and y as signed mocap axes: ``FloorPlane.parse("x-z")`` is table
    x = mocap X, table y = -mocap Z (normal +Y: the bridge's ``--up y`` mapping)."""

    a: int
    sa: float
    b: int
    sb: float

    @classmethod
    def parse(cls, text: str) -> FloorPlane:
        m = _PLANE.fullmatch(text.strip().lower())
        if not m or m[2] == m[4]:
            raise UserError(f"--plane {text!r}: give two different mocap axes for the table's x "
                            "and y, each optionally signed (xy, x-z, zx)")
        return cls(_AXIS[m[2]], -1.0 if m[1] == "-" else 1.0, _AXIS[m[4]], -1.0 if m[3] == "-" else 1.0)

    @property
    def name(self) -> str:
        def one(i: int, s: float) -> str:
            return ("-" if s < 0 else "") + "xyz"[i]
        return one(self.a, self.sa) + one(self.b, self.sb)

    @property
    def normal(self) -> str:
        """The mocap axis along the table normal (``+y``, ``-z``, ...)."""
        ea, eb = np.eye(3)[self.a] * self.sa, np.eye(3)[self.b] * self.sb
        n = np.cross(ea, eb)
        i = int(np.argmax(np.abs(n)))
        return ("+" if n[i] > 0 else "-") + "xyz"[i]

    def describe(self) -> dict[str, str]:
        """The axis mapping as run.json records it."""
        def axis(i: int, s: float) -> str:
            return ("-" if s < 0 else "") + "XYZ"[i]
        return {"plane": self.name, "x": axis(self.a, self.sa), "y": axis(self.b, self.sb),
                "normal": self.normal.replace("x", "X").replace("y", "Y").replace("z", "Z")}

    def position(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Table ``x, y`` of mocap positions ``p`` (N, 3)."""
        return self.sa * p[:, self.a], self.sb * p[:, self.b]


def quat_matrices(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (N, 3, 3) of quaternions ``q`` (N, 4) as ``(x, y, z, w)``
    (normalised here)."""
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    x, y, z, w = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], 1)


def _axis_rot(i: int, a: np.ndarray) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    if i == 0:
        rows = [[o, z, z], [z, c, -s], [z, s, c]]
    elif i == 1:
        rows = [[c, z, s], [z, o, z], [-s, z, c]]
    else:
        rows = [[c, -s, z], [s, c, z], [z, z, o]]
    return np.stack([np.stack(r, -1) for r in rows], 1)


def euler_matrices(angles_rad: np.ndarray, order: str, intrinsic: bool = True) -> np.ndarray:
    """Rotation matrices of Euler angles ``angles_rad`` (N, 3; column k the angle about
    axis ``order[k]``). Intrinsic ``XYZ`` is ``R = Rx Ry Rz`` (Vicon's Euler XYZ);
    extrinsic ``XYZ`` is ``R = Rz Ry Rx``."""
    idx = [_AXIS[c] for c in order.lower()]
    mats = [_axis_rot(i, angles_rad[:, k]) for k, i in enumerate(idx)]
    if not intrinsic:
        mats = mats[::-1]
    return mats[0] @ mats[1] @ mats[2]


def helical_matrices(v_rad: np.ndarray) -> np.ndarray:
    """Rotation matrices of rotation vectors ``v_rad`` (N, 3): axis times angle (Vicon's
    helical angles), by Rodrigues' formula."""
    ang = np.linalg.norm(v_rad, axis=1)
    safe = np.where(ang > 0, ang, 1.0)
    k = v_rad / safe[:, None]
    kx = np.zeros((len(v_rad), 3, 3))
    kx[:, 0, 1], kx[:, 0, 2], kx[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    kx[:, 1, 0], kx[:, 2, 0], kx[:, 2, 1] = k[:, 2], -k[:, 1], k[:, 0]
    s, c = np.sin(ang)[:, None, None], np.cos(ang)[:, None, None]
    return np.eye(3) + s * kx + (1 - c) * (kx @ kx)


def plane_yaw(r: np.ndarray, plane: FloorPlane) -> np.ndarray:
    """Yaw (rad, (-pi, pi]) of rotation matrices ``r`` (N, 3, 3) in ``plane``: the angle
    from the table x axis to the body's table-x axis projected onto the plane,
    counter-clockwise about the plane's normal."""
    h = plane.sa * r[:, :, plane.a]  # the body's x axis in mocap coordinates
    return np.arctan2(plane.sb * h[:, plane.b], plane.sa * h[:, plane.a])


def tilt_rad(r: np.ndarray, plane: FloorPlane) -> np.ndarray:
    """Angle between the body's normal and the table normal (rad), per frame."""
    ea, eb = np.eye(3)[plane.a] * plane.sa, np.eye(3)[plane.b] * plane.sb
    n = np.cross(ea, eb)
    return np.arccos(np.clip(np.einsum("nij,j,i->n", r, n, n), -1.0, 1.0))


def angle_gap(a: np.ndarray, b: np.ndarray) -> float:
    """Largest wrapped difference between two yaw series (rad); 0 for empty ones."""
    if len(a) == 0:
        return 0.0
    return float(np.max(np.abs(np.angle(np.exp(1j * (a - b))))))


def parse_cell(cell: str, where: str) -> float:
    """A CSV cell as a float: NaN for an empty or ``NaN`` cell (an occluded frame); text
    is a :class:`UserError` naming ``where`` (``"file: line 9, column 4 (TX)"``)."""
    s = cell.strip()
    if s == "" or s.lower() in ("nan", "-nan", "+nan"):
        return math.nan
    try:
        v = float(s)
    except ValueError:
        raise UserError(f"{where}: {cell!r} is not a number") from None
    if math.isinf(v):
        raise UserError(f"{where}: {cell!r} is not a finite number")
    return v


def data_rows(rows: list[list[str]], first_line: int, time_col: int, need: list[int],
              labels: list[str], what: str) -> tuple[np.ndarray, np.ndarray, int, int]:
    """The time cell and the ``need`` cells of every non-empty data row (``rows[k]`` is
    file line ``first_line + k``; ``labels[j]`` names column j in messages). A row with an
    empty or NaN pose cell is occluded; an empty time cell, or text anywhere, is a
    :class:`UserError`. Returns ``(times, values (N, len(need)), data rows, occluded)``."""
    times, vals, n_rows, n_occ = [], [], 0, 0
    for k, row in enumerate(rows):
        if not any(c.strip() for c in row):
            continue
        ln = first_line + k
        n_rows += 1
        t = parse_cell(row[time_col] if time_col < len(row) else "",
                       f"{what}: line {ln}, column {time_col + 1} ({labels[time_col]})")
        if math.isnan(t):
            raise UserError(f"{what}: line {ln}: the {labels[time_col]} cell is empty")
        v = [parse_cell(row[j], f"{what}: line {ln}, column {j + 1} ({labels[j]})") if j < len(row)
             else math.nan for j in need]
        if any(math.isnan(x) for x in v):
            n_occ += 1
            continue
        times.append(t)
        vals.append(v)
    return np.array(times, float), np.array(vals, float).reshape(-1, len(need)), n_rows, n_occ


def finish(t_source_s: np.ndarray, x_m: np.ndarray, y_m: np.ndarray, psi_rad: np.ndarray,
           frames: int, occluded: int, source: dict[str, Any], what: str) -> PoseTable:
    """A :class:`PoseTable` of the kept frames: a frame whose time equals the previous
    kept frame's is dropped (counted as ``repeated``); time that goes back is a
    :class:`UserError`; no kept frame at all is one too."""
    if len(t_source_s) == 0:
        raise UserError(f"{what}: no frame with a pose ({frames} data rows, {occluded} occluded)")
    dt = np.diff(t_source_s)
    back = np.flatnonzero(dt < 0)
    if len(back):
        i = int(back[0]) + 1
        raise UserError(f"{what}: time goes back at kept frame {i + 1} "
                        f"({t_source_s[i - 1]:.9g} s then {t_source_s[i]:.9g} s)")
    keep = np.concatenate([[True], dt > 0])
    t0 = float(t_source_s[0])
    psi = np.angle(np.exp(1j * psi_rad[keep]))
    psi[psi <= -math.pi] = math.pi
    counts = {"frames": int(frames), "kept": int(keep.sum()), "occluded": int(occluded),
              "repeated": int((~keep).sum())}
    return PoseTable(t_source_s[keep] - t0, x_m[keep], y_m[keep], psi, t0, counts, source)


AGREE_RAD = 1e-3
"""Two readings of an undeclared rotation convention must give the same yaw within this."""

LEVEL_DEG = 10.0
"""A body on an air-bearing table or a floor stays within this of level (deg, every frame)."""

TILTED_DEG = 30.0
"""...and a reading that tilts it beyond this somewhere is not the file's convention: when
exactly one convention keeps the body level and every other tilts it this far, that one is
chosen (a Vicon Tracker export of a ground robot whose helical vector passes 2 pi reads
1.7 deg of tilt as helical and 136 deg as Euler XYZ, docs/real-data.md)."""


def resolve_yaw(candidates: dict[str, np.ndarray], plane: FloorPlane, given: str | None,
                what: str, option: str = "--rotation") -> tuple[np.ndarray, str]:
    """The yaw of rotation matrices read under a convention the file does not declare.

    ``candidates`` maps each convention the file may use to its matrices (N, 3, 3). With
    ``given`` (the user's choice) that one is used. Otherwise the conventions must agree
    on the yaw of every frame within :data:`AGREE_RAD` (they do for a level body, as on
    an air-bearing table), or exactly one of them must keep the body level
    (:data:`LEVEL_DEG`, every other tilting it past :data:`TILTED_DEG`); otherwise a
    :class:`UserError` asks for ``option``.
    Returns the yaw and the note run.json records."""
    if given is not None:
        if given not in candidates:
            raise UserError(f"{option} {given!r}: choose one of {', '.join(candidates)}")
        return plane_yaw(candidates[given], plane), f"{given} (given)"
    names = list(candidates)
    yaws = [plane_yaw(candidates[n], plane) for n in names]
    if len(names) == 1:
        return yaws[0], names[0]
    gap = max((angle_gap(yaws[0], y) for y in yaws[1:]), default=0.0)
    if gap > AGREE_RAD:
        tilt = {n: float(np.degrees(np.max(tilt_rad(candidates[n], plane), initial=0.0)))
                for n in names}
        level = [n for n in names if tilt[n] <= LEVEL_DEG]
        if len(level) == 1 and all(tilt[n] >= TILTED_DEG for n in names if n != level[0]):
            k = names.index(level[0])
            others = ", ".join(f"{tilt[n]:.3g} deg as {n}" for n in names if n != level[0])
            return yaws[k], (f"{level[0]} (undeclared; the only reading that keeps the body "
                             f"level: max tilt {tilt[level[0]]:.2g} deg, against {others})")
        raise UserError(f"{what}: the file does not say whether its angles are "
                        f"{' or '.join(names)}, and the yaw differs by up to "
                        f"{math.degrees(gap):.3g} deg between them (the body tilts); "
                        f"give {option} {'|'.join(names)}")
    return yaws[0], f"{' = '.join(names)} (undeclared; yaw agrees within {math.degrees(gap):.2g} deg)"
