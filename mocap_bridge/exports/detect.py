"""Which export a pose file is, from its first lines, and the reader for it.

- ``Format Version,...`` on line 1: an OptiTrack Motive export (:mod:`.motive_csv`).
- A line ``Objects``, ``Segments`` or ``Trajectories`` (then the frame rate) in the first
  lines: a Vicon Tracker or Nexus export (:mod:`.vicon_csv`).
- Anything else: a plain CSV, read only through a column map (:mod:`.generic_csv`).

With a column map the file is always read as a plain CSV.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from common.errors import UserError
from mocap_bridge.exports.generic_csv import POSE_KEYS, parse_column_map, read_generic_csv
from mocap_bridge.exports.motive_csv import read_motive_csv
from mocap_bridge.exports.table import FloorPlane, PoseTable
from mocap_bridge.exports.vicon_csv import OTHER_SECTIONS, POSE_SECTIONS, read_vicon_csv

FORMATS = ("motive", "vicon", "generic")
_SCAN_LINES = 40


def detect_format(text: str) -> str:
    """``"motive"``, ``"vicon"`` or ``"generic"`` from the first lines of ``text``."""
    lines = text.lstrip("\ufeff").splitlines()[:_SCAN_LINES]
    if lines and lines[0].startswith("Format Version"):
        return "motive"
    for i, line in enumerate(lines[:-1]):
        head = re.split(r"[,;]", line.strip(), maxsplit=1)[0].strip()
        nxt = re.split(r"[,;]", lines[i + 1].strip(), maxsplit=1)[0].strip()
        if head in POSE_SECTIONS + OTHER_SECTIONS and re.fullmatch(r"\d+(\.\d*)?", nxt):
            return "vicon"
    return "generic"


@dataclass
class PoseOptions:
    """What the user said about a pose file (every field optional)."""

    body: str | None = None
    columns: str | None = None
    units: str | None = None        # "mm,deg"
    time_unit: str | None = None
    plane: str | None = None
    yaw_sign: float = 1.0
    rotation: str | None = None


def split_units(text: str | None, option: str = "--units", example: str = "mm,deg"
                ) -> tuple[str | None, str | None]:
    """``LENGTH,ANGLE`` (either may be empty; None: neither given) as the two unit names;
    more than two is refused naming ``option``."""
    if text is None:
        return None, None
    parts = [p.strip() or None for p in text.split(",")]
    if len(parts) > 2:
        raise UserError(f"{option} {text!r}: give LENGTH,ANGLE (e.g. {example})")
    return parts[0], parts[1] if len(parts) > 1 else None


def read_poses(text: str, options: PoseOptions, what: str = "file") -> PoseTable:
    """Planar poses of a pose export of any supported format (see the module doc)."""
    text = text.lstrip("\ufeff")
    plane = FloorPlane.parse(options.plane) if options.plane else None
    length, angle = split_units(options.units)
    if options.columns is not None:
        for name, value in (("--body", options.body), ("--rotation", options.rotation)):
            if value is not None:
                raise UserError(f"{name} is for Vicon and Motive exports; a --columns file holds one "
                                "body and names its orientation columns")
        cols = parse_column_map(options.columns, POSE_KEYS)
        return read_generic_csv(text, cols, plane=plane, units=(length, angle),
                                time_unit=options.time_unit, yaw_sign=options.yaw_sign, what=what)
    fmt = detect_format(text)
    if fmt == "generic":
        raise UserError(f"{what}: not a Vicon or Motive export (no 'Format Version' line, no "
                        "Objects/Segments section); give the columns with --columns t=COL,x=COL,y=COL,yaw=COL")
    if options.time_unit is not None:
        raise UserError(f"--time-unit: a {fmt} export states its time; the option is for --columns files")
    given = (length, angle) if options.units is not None else None
    reader = read_motive_csv if fmt == "motive" else read_vicon_csv
    table = reader(text, body=options.body, plane=plane, units=given, rotation=options.rotation, what=what)
    if options.yaw_sign != 1.0:
        table.psi_rad = options.yaw_sign * table.psi_rad
        table.source["yaw_sign"] = options.yaw_sign
    return table
