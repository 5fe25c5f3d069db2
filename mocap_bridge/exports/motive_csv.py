"""OptiTrack Motive CSV exports (format versions 1.1x to 1.2x).

The layout, as OptiTrack's "Data Export: CSV" page and the export itself show it (a real
1.21 export is runs/fixtures/real/hmv-s16-motive/; tests/mocap_bridge/exports/
test_motive_csv.py cites the 1.23+ layout)::

    Format Version,1.21,Take Name,...,Rotation Type,Quaternion,Length Units,Meters,Coordinate Space,Global
                                                  <- empty line
    ,,Rigid Body,Rigid Body,...,Rigid Body Marker,...,Marker,...      <- type   (1.23+: ",Type,...")
    ,,Rigid Body 1,Rigid Body 1,...                                   <- name   (",Name,...")
    ,,"CF5107FC...","CF5107FC...",...                                 <- ID     (",ID,..."; 1.24+ ",Parent,...")
    ,,Rotation,Rotation,Rotation,Rotation,Position,Position,Position,Error Per Marker,...
    Frame,Time,X,Y,Z,W,X,Y,Z,,...                 <- 1.23+: "Frame,Time (Seconds),..."
    0,0.000000,0.000035,...                       <- empty cells: not tracked in that frame

``Rotation Type`` is ``Quaternion`` (X, Y, Z, W) or an Euler order (``XYZ``, ``ZYX``, ...,
degrees; intrinsic or extrinsic the header does not say, so it is accepted when both give
the same yaw). Motive is Y-up: the default floor plane is ``x-z`` (table x = Motive X,
table y = -Motive Z, normal +Y: the bridge's ``--up y``); ``zx`` is the other common one.
"""

from __future__ import annotations

import csv
import io

import numpy as np

from common.errors import UserError
from mocap_bridge.exports.table import (
    FloorPlane,
    PoseTable,
    data_rows,
    euler_matrices,
    finish,
    length_factor,
    quat_matrices,
    resolve_yaw,
)
from mocap_bridge.exports.vicon_csv import pick_body

DEFAULT_PLANE = "x-z"
_LABELS = ("Type", "Name", "ID", "Parent")


def header_fields(first_row: list[str]) -> dict[str, str]:
    """The key/value pairs of the ``Format Version,...`` line."""
    return {first_row[i].strip(): first_row[i + 1].strip() for i in range(0, len(first_row) - 1, 2)}


def _header_rows(rows: list[list[str]], frame_row: int) -> tuple[dict[str, list[str]], list[str]]:
    """The labelled rows (Type, Name, ID, Parent) and the component row above the column row."""
    block = [r for r in rows[1:frame_row] if any(c.strip() for c in r)]
    if not block:
        return {}, []
    component = block[-1]
    labelled = {r[1].strip(): r for r in block[:-1] if len(r) > 1 and r[1].strip() in _LABELS}
    if not labelled:  # 1.21 and older: Type, Name, ID in that order, no labels
        labelled = dict(zip(("Type", "Name", "ID"), block[:-1], strict=False))
    return labelled, component


def read_motive_csv(text: str, *, body: str | None = None, plane: FloorPlane | None = None,
                    units: tuple[str | None, str | None] | None = None, rotation: str | None = None,
                    what: str = "file") -> PoseTable:
    """Planar poses of one rigid body of a Motive CSV export (see the module doc).

    ``units``: (length, angle) when the header has no ``Length Units`` (a given length
    unit must match the header's). ``rotation``: ``intrinsic`` or ``extrinsic`` for an
    Euler export of a tilted body."""
    plane = plane or FloorPlane.parse(DEFAULT_PLANE)
    rows = list(csv.reader(io.StringIO(text)))
    if not rows or not rows[0] or rows[0][0].strip() != "Format Version":
        raise UserError(f"{what}: not a Motive CSV export (line 1 does not start with 'Format Version')")
    meta = header_fields(rows[0])
    frame_row = next((i for i, r in enumerate(rows) if len(r) > 1 and r[0].strip() == "Frame"
                      and r[1].strip().startswith("Time")), None)
    if frame_row is None:
        raise UserError(f"{what}: the header is cut short: no 'Frame,Time,...' column row")
    labelled, component = _header_rows(rows, frame_row)
    if "Type" not in labelled or "Name" not in labelled or not component:
        raise UserError(f"{what}: the header is cut short above line {frame_row + 1} "
                        "(want the Type, Name and Rotation/Position rows)")
    axes, types, names = rows[frame_row], labelled["Type"], labelled["Name"]

    def cell(r: list[str], k: int) -> str:
        return r[k].strip() if k < len(r) else ""

    bodies = [n for n in dict.fromkeys(cell(names, k) for k in range(2, len(axes))
                                       if cell(types, k) == "Rigid Body") if n]
    if not bodies:
        raise UserError(f"{what}: no Rigid Body columns (only {', '.join(sorted({cell(types, k) for k in range(2, len(axes))} - {''}))})")
    chosen = pick_body(bodies, body, what)
    idx = {}
    for k in range(2, len(axes)):
        if cell(types, k) == "Rigid Body" and cell(names, k) == chosen:
            idx[(cell(component, k), cell(axes, k))] = k
    rot_type = meta.get("Rotation Type", "Quaternion")
    quat = rot_type.lower() == "quaternion"
    want_rot = [("Rotation", a) for a in (("X", "Y", "Z", "W") if quat else tuple(rot_type.upper()))]
    want_pos = [("Position", a) for a in "XYZ"]
    missing = [f"{c} {a}" for c, a in want_pos + want_rot if (c, a) not in idx]
    if missing:
        raise UserError(f"{what}: line {frame_row + 1}: rigid body {chosen} has no column {', '.join(missing)}")
    len_unit = _length_unit(meta.get("Length Units"), units, what)
    need = [idx[w] for w in want_pos + want_rot]
    labels = [f"{chosen} {c}" if k >= 2 else c for k, c in enumerate(axes)]
    times, a, frames, n_occ = data_rows(rows[frame_row + 1:], frame_row + 2, 1, need, labels, what)
    p = a[:, :3] * length_factor(len_unit)
    if quat:
        psi, note = resolve_yaw({"quaternion": quat_matrices(a[:, 3:7])}, plane, None, what)
    else:
        r = np.radians(a[:, 3:6])
        psi, note = resolve_yaw({"intrinsic": euler_matrices(r, rot_type, True),
                                 "extrinsic": euler_matrices(r, rot_type, False)}, plane, rotation, what)
    x, y = plane.position(p)
    source = {"format": "motive-csv", "format_version": meta.get("Format Version"), "body": chosen,
              "rate_hz": _rate(meta), "units": {"length": len_unit, "angle": "quaternion" if quat else "deg"},
              "rotation_type": rot_type, "rotation": note, "axes": plane.describe(),
              "coordinate_space": meta.get("Coordinate Space")}
    return finish(times, x, y, psi, frames, n_occ, source, what)


def _rate(meta: dict[str, str]) -> float | None:
    try:
        return float(meta.get("Export Frame Rate", ""))
    except ValueError:
        return None


def _length_unit(header: str | None, given: tuple[str | None, str | None] | None, what: str) -> str:
    want = given[0] if given else None
    if header and want and length_factor(header) != length_factor(want):
        raise UserError(f"{what}: line 1 says Length Units {header}, --units says {want}")
    unit = header or want
    if not unit:
        raise UserError(f"{what}: line 1 has no Length Units; give the unit with --units LENGTH,deg")
    length_factor(unit)
    return unit
