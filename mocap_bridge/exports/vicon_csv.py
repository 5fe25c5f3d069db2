"""Vicon CSV exports: Tracker's ``Objects`` and Nexus's ``Segments`` sections.

The layout, as Vicon's Tracker help ("Exporting data to CSV", Tracker 4.1) and other
people's readers (tests/mocap_bridge/exports/test_vicon_csv.py cites them) show it::

    Objects                                   <- section: Objects (Tracker), Segments (Nexus)
    100                                       <- frame rate, Hz
    ,,Global Angle body:body,,,Global Position body:body,,   <- (Tracker) or ,,Subject:Seg,,,,,
    Frame,Sub Frame,RX,RY,RZ,TX,TY,TZ         <- columns (RW too for quaternion exports)
    ,,rad,rad,rad,mm,mm,mm                    <- units
    1,0,0.01,-0.02,1.57,100.5,200.25,50.0     <- data; empty cells: the object was not seen

A Nexus file may hold several sections (Devices, Joints, Segments, Trajectories, ...),
each ended by an empty line; the ``Objects`` or ``Segments`` one is read. ``Trajectories``
(marker positions) hold no orientation and are refused with a hint. Rotations: ``RX, RY,
RZ, RW`` is a quaternion; ``RX, RY, RZ`` is Euler XYZ or helical, which the file does not
say: :func:`~mocap_bridge.exports.table.resolve_yaw` accepts it when both give the same
yaw (a level body) and asks for ``--rotation`` otherwise.
"""

from __future__ import annotations

import csv
import io
import re

from common.errors import UserError
from mocap_bridge.exports.table import (
    FloorPlane,
    PoseTable,
    angle_factor,
    data_rows,
    euler_matrices,
    finish,
    helical_matrices,
    length_factor,
    quat_matrices,
    resolve_yaw,
)

POSE_SECTIONS = ("Objects", "Segments")
OTHER_SECTIONS = ("Trajectories", "Devices", "Joints", "Model Outputs")
_PREFIX = re.compile(r"^Global (Angle|Position)\s*(\(([^)]*)\))?\s*", re.IGNORECASE)


def _rows(text: str, delim: str) -> list[list[str]]:
    return list(csv.reader(io.StringIO(text), delimiter=delim))


def find_section(lines: list[str]) -> tuple[str, int, int]:
    """``(name, first line, end line)`` of the pose section (0-based, end exclusive)."""
    starts = []
    for i, line in enumerate(lines):
        head = re.split(r"[,;]", line.strip(), maxsplit=1)[0].strip()
        if head in POSE_SECTIONS + OTHER_SECTIONS:
            starts.append((head, i))
    for name, i in starts:
        if name in POSE_SECTIONS:
            end = next((j for j in range(i + 1, len(lines)) if lines[j].strip(" ,;\r") == ""),
                       len(lines))
            return name, i, end
    if starts:
        found = ", ".join(sorted({n for n, _ in starts}))
        raise UserError(f"a Vicon export with {found} but no Objects or Segments section: marker "
                        "trajectories hold no orientation; export the object (Tracker) or the "
                        "segments (Nexus), or import the columns with --columns")
    raise UserError("not a Vicon CSV export (no Objects or Segments line)")


def _bodies(name_row: list[str], ncol: int) -> tuple[list[str], dict[str, str]]:
    """The body of each column (carried right from the cell naming it) and any rotation
    type the name cells declare (``Global Angle (Quaternion) b:b``)."""
    body, out, declared = "", [], {}
    for k in range(ncol):
        cell = name_row[k].strip() if k < len(name_row) else ""
        if cell:
            m = _PREFIX.match(cell)
            body = cell[m.end():].strip() if m else cell
            if m and m[1].lower() == "angle" and m[3]:
                declared[body] = m[3].strip().lower()
        out.append(body)
    return out, declared


def pick_body(names: list[str], body: str | None, what: str) -> str:
    """The body ``--body`` names (exactly, or its subject or segment part); the only one
    when not given."""
    if body is None:
        if len(names) == 1:
            return names[0]
        raise UserError(f"{what} holds {len(names)} bodies ({', '.join(names)}); choose one with --body")
    hits = [n for n in names if n == body] or [n for n in names if body in n.split(":")]
    if len(hits) != 1:
        why = "no body" if not hits else f"{len(hits)} bodies"
        raise UserError(f"--body {body}: {what} has {why} of that name (bodies: {', '.join(names)})")
    return hits[0]


def read_vicon_csv(text: str, *, body: str | None = None, plane: FloorPlane | None = None,
                   units: tuple[str | None, str | None] | None = None, rotation: str | None = None,
                   what: str = "file") -> PoseTable:
    """Planar poses of one body of a Vicon Tracker/Nexus CSV export (see the module doc).

    ``plane``: the floor plane (default ``xy``: Vicon is Z-up). ``units``: (length, angle)
    when the file has no units row (given units must match the file's). ``rotation``:
    ``euler-xyz`` or ``helical`` for ``RX, RY, RZ`` columns of a tilted body."""
    plane = plane or FloorPlane.parse("xy")
    lines = text.splitlines()
    section, i0, end = find_section(lines)
    if end - i0 < 4:
        raise UserError(f"{what}: the {section} header is cut short (line {i0 + 1} onwards: "
                        "section, rate, names, columns, units)")
    try:
        rate_hz = float(re.split(r"[,;]", lines[i0 + 1])[0])
    except ValueError:
        raise UserError(f"{what}: line {i0 + 2}: the frame rate {lines[i0 + 1]!r} is not a number") from None
    if not rate_hz > 0:
        raise UserError(f"{what}: line {i0 + 2}: the frame rate {rate_hz:g} Hz is not positive")
    col_line = next((j for j in range(i0 + 1, end) if re.match(r"\s*Frame\s*[,;]\s*Sub Frame", lines[j])), None)
    if col_line is None:
        raise UserError(f"{what}: no 'Frame,Sub Frame,...' column row in the {section} section")
    delim = ";" if ";" in lines[col_line] and "," not in lines[col_line] else ","
    cols = [c.strip() for c in _rows(lines[col_line], delim)[0]]
    name_row = _rows(lines[col_line - 1], delim)[0] if col_line - 1 > i0 + 1 else []
    col_body, declared = _bodies(name_row, len(cols))
    names = [n for n in dict.fromkeys(col_body[2:]) if n]
    if not names:
        raise UserError(f"{what}: line {col_line}: no object names above the column row")
    chosen = pick_body(names, body, what)
    idx = {c: k for k, c in enumerate(cols) if col_body[k] == chosen and c in ("RX", "RY", "RZ", "RW", "TX", "TY", "TZ")}
    missing = [c for c in ("RX", "RY", "RZ", "TX", "TY", "TZ") if c not in idx]
    if missing:
        raise UserError(f"{what}: line {col_line + 1}: body {chosen} has no column {', '.join(missing)}")
    unit_line = col_line + 1
    unit_row = _rows(lines[unit_line], delim)[0] if unit_line < end else []
    has_units = bool(unit_row) and unit_row[0].strip() == ""  # data rows start with a frame number
    file_len = unit_row[idx["TX"]].strip() if has_units and idx["TX"] < len(unit_row) else None
    file_ang = unit_row[idx["RX"]].strip() if has_units and idx["RX"] < len(unit_row) else None
    quat = "RW" in idx or declared.get(chosen, "").startswith("quat")
    len_unit, ang_unit = _units(file_len, file_ang, units, quat, what, unit_line)
    first = unit_line + 1 if has_units else unit_line
    rows = _rows("\n".join(lines[first:end]), delim)
    need = [idx[c] for c in ("TX", "TY", "TZ", "RX", "RY", "RZ")] + ([idx["RW"]] if "RW" in idx else [])
    frames, a, n_rows, n_occ = data_rows(rows, first + 1, 0, need, cols, what)
    p = a[:, :3] * length_factor(len_unit)
    rot = a[:, 3:]
    if quat:
        psi, note = resolve_yaw({"quaternion": quat_matrices(rot[:, [0, 1, 2, 3]])}, plane, None, what)
    else:
        kind = declared.get(chosen, "")
        said = rotation is None and ("helical" in kind or "euler" in kind or "xyz" in kind)
        if said:
            rotation = "helical" if "helical" in kind else "euler-xyz"  # the file says which
        r = rot * angle_factor(ang_unit)
        psi, note = resolve_yaw({"euler-xyz": euler_matrices(r, "xyz"), "helical": helical_matrices(r)},
                                plane, rotation, what)
        if said:
            note = note.replace("(given)", "(named in the header)")
    x, y = plane.position(p)
    source = {"format": f"vicon-{'tracker' if section == 'Objects' else 'nexus'}-csv",
              "section": section, "body": chosen, "rate_hz": rate_hz,
              "units": {"length": len_unit, "angle": "quaternion" if quat else ang_unit},
              "rotation": note, "axes": plane.describe()}
    return finish(frames / rate_hz, x, y, psi, n_rows, n_occ, source, what)


def _units(file_len: str | None, file_ang: str | None, given: tuple[str | None, str | None] | None,
           quat: bool, what: str, line: int) -> tuple[str, str]:
    """The length and angle units: the file's units row, checked against ``given``."""
    given = given or (None, None)
    for have, want, kind in ((file_len, given[0], "length"), (file_ang, given[1], "angle")):
        if have and want and have.lower() != want.lower() and not (kind == "angle" and quat):
            raise UserError(f"{what}: line {line + 1} says {kind} unit {have!r}, --units says {want!r}")
    length, angle = given[0] or file_len, given[1] or file_ang
    if length is None or (angle is None and not quat):
        raise UserError(f"{what}: no units row under the column row (line {line + 1}); "
                        "give the units with --units LENGTH,ANGLE (e.g. mm,rad)")
    return length, angle or "rad"
