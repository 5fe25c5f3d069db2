"""Any CSV with a header row, read through a column map and units.

``--columns t=COL,x=COL,y=COL,yaw=COL`` names the file's columns (by header name, or by
1-based number): ``t`` (required), positions ``x``, ``y`` and optionally ``z`` (mocap axes;
``--plane`` picks the floor's two, default ``xy``), and the orientation as ``yaw`` (the
table yaw itself, times ``--yaw-sign``) or ``qx,qy,qz,qw`` (a quaternion; yaw about the
plane's normal). Units: ``--units LENGTH,ANGLE`` and ``--time-unit``; a unit the column
names do not state (``Telemetry_X_mm``, ``yaw_deg``, ``Time (Seconds)``) must be given,
and a given unit that contradicts a name is refused. Nothing is guessed.

The same column-map and unit rules serve the command logs (:mod:`.command_log`).
"""

from __future__ import annotations

import csv
import io
import re

import numpy as np

from common.errors import UserError
from mocap_bridge.exports.table import (
    ANGLE_RAD,
    LENGTH_M,
    TIME_S,
    FloorPlane,
    PoseTable,
    angle_factor,
    finish,
    length_factor,
    parse_cell,
    plane_yaw,
    quat_matrices,
    time_factor,
)

POSE_KEYS = ("t", "x", "y", "z", "yaw", "qx", "qy", "qz", "qw")
_UNIT_IN_NAME = re.compile(r"(?:[_\s(\[]|^)([a-z]+)[)\]]?\s*$", re.IGNORECASE)


def parse_column_map(text: str, keys: tuple[str, ...], option: str = "--columns") -> dict[str, str]:
    """``"t=Time,x=X_mm"`` as ``{"t": "Time", "x": "X_mm"}``; an unknown key is refused."""
    out: dict[str, str] = {}
    for part in filter(None, (p.strip() for p in text.split(","))):
        key, eq, col = part.partition("=")
        key = key.strip().lower()
        if not eq or not col.strip():
            raise UserError(f"{option} {text!r}: {part!r} is not KEY=COLUMN")
        if key not in keys:
            raise UserError(f"{option}: unknown key {key!r} (keys: {', '.join(keys)})")
        if key in out:
            raise UserError(f"{option}: {key} given twice")
        out[key] = col.strip()
    return out


def read_table_text(text: str, what: str) -> tuple[list[str], list[tuple[int, list[str]]]]:
    """The header and the non-empty data rows (with their 1-based line numbers).

    The separator is read off the header line (it holds no decimals): a spreadsheet of a
    decimal-comma locale writes ``time;x;y`` and ``0,05;1,25;...`` (or tabs), whose number
    cells are read with the comma as the decimal point; a cell that is not a number so
    (a vector ``[1, 0]``) is left as it is."""
    from common.csv_locale import decimal_commas, header_delimiter

    delim = header_delimiter(text.lstrip("\ufeff").split("\n", 1)[0]) or ","
    rows = list(csv.reader(io.StringIO(text), delimiter=delim))
    if delim != ",":
        rows = decimal_commas(rows)
    if not rows or not any(c.strip() for c in rows[0]):
        raise UserError(f"{what}: empty file or empty header line")
    header = [c.strip() for c in rows[0]]
    return header, [(i + 1, r) for i, r in enumerate(rows) if i > 0 and any(c.strip() for c in r)]


def column_index(header: list[str], col: str, key: str, what: str) -> int:
    """The index of column ``col`` (a header name, or a 1-based number)."""
    if col in header:
        return header.index(col)
    if col.isdigit() and 1 <= int(col) <= len(header):
        return int(col) - 1
    raise UserError(f"{what}: no column {col!r} (for {key}) in the header line")


def unit_in_name(name: str, table: dict[str, float]) -> str | None:
    """The unit a column name states at its end (``X_mm``, ``Time (Seconds)``), if any."""
    m = _UNIT_IN_NAME.search(name)
    if m and m[1].lower() in table:
        return m[1].lower()
    return None


def resolve_unit(names: list[str], given: str | None, table: dict[str, float], kind: str,
                 option: str, what: str) -> str:
    """The unit of columns ``names``: the given one (checked against the names) or the
    one their names state; a :class:`UserError` when neither says."""
    stated = {n: u for n in names if (u := unit_in_name(n, table))}
    for n, u in stated.items():
        if given is not None and table[u] != table.get(given.lower(), -1.0):
            raise UserError(f"{what}: column {n!r} says {kind} unit {u!r}, {option} says {given!r}")
    if given is not None:
        if given.lower() not in table:
            raise UserError(f"{option}: unknown {kind} unit {given!r} (known: "
                            f"{', '.join(k for k in table if len(k) <= 3)})")
        return given.lower()
    units = {table[u] for u in stated.values()}
    if len(units) > 1:
        raise UserError(f"{what}: columns {', '.join(stated)} state different {kind} units")
    if not stated or len(stated) < len(names):
        unnamed = [n for n in names if n not in stated]
        raise UserError(f"{what}: the {kind} unit of column {', '.join(map(repr, unnamed))} is not "
                        f"stated; give it with {option}")
    return next(iter(stated.values()))


def read_generic_csv(text: str, columns: dict[str, str], *, plane: FloorPlane | None = None,
                     units: tuple[str | None, str | None] = (None, None), time_unit: str | None = None,
                     yaw_sign: float = 1.0, what: str = "file") -> PoseTable:
    """Planar poses from the columns ``columns`` maps (see the module doc)."""
    plane = plane or FloorPlane.parse("xy")
    if "t" not in columns:
        raise UserError("--columns: give the time column (t=COL)")
    quat_keys = ("qx", "qy", "qz", "qw")
    has_q = [k for k in quat_keys if k in columns]
    if "yaw" in columns and has_q:
        raise UserError("--columns: give yaw=COL or qx,qy,qz,qw, not both")
    if not ("yaw" in columns or len(has_q) == 4):
        raise UserError("--columns: give the orientation: yaw=COL, or qx=,qy=,qz=,qw= (all four)")
    need_axes = ["xyz"[plane.a], "xyz"[plane.b]]
    for ax in need_axes:
        if ax not in columns:
            raise UserError(f"--columns: the floor plane {plane.name} needs the {ax} column ({ax}=COL)")
    header, rows = read_table_text(text, what)
    keys = ["t", *need_axes, *(["yaw"] if "yaw" in columns else quat_keys)]
    idx = {k: column_index(header, columns[k], k, what) for k in keys}
    t_unit = resolve_unit([header[idx["t"]]], time_unit, TIME_S, "time", "--time-unit", what)
    l_unit = resolve_unit([header[idx[a]] for a in need_axes], units[0], LENGTH_M, "length", "--units", what)
    a_unit = (resolve_unit([header[idx["yaw"]]], units[1], ANGLE_RAD, "angle", "--units", what)
              if "yaw" in columns else "quaternion")
    vals, n_occ = [], 0
    for ln, row in rows:
        v = []
        for k in keys:
            j = idx[k]
            if j >= len(row):
                raise UserError(f"{what}: line {ln} has {len(row)} cells; column {header[j]!r} is missing")
            v.append(parse_cell(row[j], f"{what}: line {ln}, column {j + 1} ({header[j]})"))
        if np.isnan(v[0]):
            raise UserError(f"{what}: line {ln}: the time cell ({header[idx['t']]}) is empty")
        if np.isnan(v).any():
            n_occ += 1
            continue
        vals.append(v)
    a = np.array(vals, float).reshape(-1, len(keys))
    t = a[:, 0] * time_factor(t_unit)
    pos = np.zeros((len(a), 3))
    pos[:, plane.a], pos[:, plane.b] = a[:, 1], a[:, 2]
    x, y = plane.position(pos * length_factor(l_unit))
    if "yaw" in columns:
        psi = yaw_sign * a[:, 3] * angle_factor(a_unit)
    else:
        psi = yaw_sign * plane_yaw(quat_matrices(a[:, 3:7]), plane)
    source = {"format": "generic-csv", "columns": {k: header[idx[k]] for k in keys},
              "units": {"time": t_unit, "length": l_unit, "angle": a_unit}, "yaw_sign": yaw_sign,
              "axes": plane.describe()}
    return finish(t, x, y, psi, len(rows), n_occ, source, what)
