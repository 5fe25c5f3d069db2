"""``--time-from``: a CSV's true row times from its own columns, beside its nominal time column.

``--time-from vx=COL,vy=COL,wz=COL,x=COL,y=COL,yaw=COL`` names logged finite-difference
velocities and the positions they differentiate (any of the pairs x/vx, y/vy, yaw/wz; the
velocities per second in the positions' units, which ``--time-from-units LENGTH,ANGLE`` or
the position columns' names state); ``--time-from dt=COL`` names a column holding each row's
interval since the previous row (unit: ``--time-unit`` or its name). Every data row gets a
time: the first its nominal one, the next ones the rebuilt intervals
(:mod:`.time_base`). The result maps nominal times to rebuilt ones, so the poses and the
commands of the same rows land on the same clock.

A cell that is not a number is counted (``bad_cells``) and its interval filled, never an
error; a column that cannot be what it is named for is one error line.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from common.errors import UserError
from mocap_bridge.exports.generic_csv import (
    column_index,
    parse_column_map,
    read_table_text,
    resolve_unit,
)
from mocap_bridge.exports.table import ANGLE_RAD, LENGTH_M, TIME_S, parse_cell
from mocap_bridge.exports.time_base import (
    DETERMINED,
    DISAGREE,
    Intervals,
    intervals_from_column,
    intervals_from_velocities,
    summary,
    times_from,
)

KEYS = ("dt", "x", "y", "yaw", "vx", "vy", "wz")
PAIRS = (("x", "vx"), ("y", "vy"), ("yaw", "wz"))
OPTION = "--time-from"
UNITS_OPTION = "--time-from-units"
_NUMBER = re.compile(r"[+-]?(\d*)(?:\.(\d*))?(?:[eE]([+-]?\d+))?")


def parse_time_from(text: str) -> dict[str, str]:
    """The ``--time-from`` map, checked: ``dt`` alone, or velocity/position pairs."""
    cols = parse_column_map(text, KEYS, OPTION)
    if "dt" in cols:
        if len(cols) > 1:
            raise UserError(f"{OPTION}: give dt=COL alone, or the velocities and positions "
                            "(vx=,x=, vy=,y=, wz=,yaw=), not both")
        return cols
    for p, v in PAIRS:
        if (p in cols) != (v in cols):
            have, need = (p, v) if p in cols else (v, p)
            raise UserError(f"{OPTION}: {have}= needs {need}= (a velocity and the position it differentiates)")
    if not cols:
        raise UserError(f"{OPTION}: give dt=COL, or vx=COL,x=COL (and/or vy=,y=, wz=,yaw=)")
    return cols


@dataclass
class TimeBase:
    """Every data row's nominal time and its rebuilt time (s, on the source's clock), and
    what run.json keeps of it (:func:`~mocap_bridge.exports.time_base.summary` and
    ``bad_cells``, ``columns``)."""

    t_nominal: np.ndarray
    t: np.ndarray
    summary: dict


def _digits(cell: str) -> tuple[int, int] | None:
    """(decimals, significant digits) of a number as written: ``0.0125`` (4, 3), ``1e-05`` (5, 1)."""
    m = _NUMBER.fullmatch(cell.strip())
    if not m or not (m[1] or m[2]):
        return None
    frac = m[2] or ""
    digits = ((m[1] or "") + frac).lstrip("0")
    return len(frac) - int(m[3] or 0), max(len(digits), 1)


def _column(rows, j: int, name: str, key: str) -> tuple[np.ndarray, np.ndarray, int]:
    """A column's values (NaN for an empty or bad cell), the resolution each cell is written
    to (half a last digit, from the column's most decimals and significant digits; at least
    the float's own), and the number of bad cells."""
    vals = np.full(len(rows), math.nan)
    dec, sig, bad = -99, 1, 0
    for i, (_, row) in enumerate(rows):
        cell = row[j] if j < len(row) else ""
        try:
            vals[i] = parse_cell(cell, "")
        except UserError:
            bad += 1
            continue
        if not math.isnan(vals[i]) and (d := _digits(cell)):
            dec, sig = max(dec, d[0]), max(sig, d[1])
    if not np.isfinite(vals).any():
        raise UserError(f"{OPTION}: column {name!r} ({key}) holds no number")
    mag = np.floor(np.log10(np.abs(np.where(np.isfinite(vals) & (vals != 0), vals, 1.0))))
    q = np.maximum(10.0 ** (-dec), 10.0 ** (mag - sig + 1))
    return vals, 0.5 * np.maximum(q, np.abs(np.spacing(np.nan_to_num(vals)))), bad


def _velocity_intervals(rows, header, idx, cols, units, what) -> tuple[Intervals, int, dict]:
    n = len(rows)
    pos, vel = np.full((n, 3), math.nan), np.full((n, 3), math.nan)
    qp, qv = np.ones((n, 3)), np.ones((n, 3))
    given = [k for k, _ in PAIRS if k in cols]
    length = angle = None
    if "x" in cols or "y" in cols:
        length = resolve_unit([header[idx[k]] for k in ("x", "y") if k in cols], units[0], LENGTH_M,
                              "length", UNITS_OPTION, what)
    if "yaw" in cols:
        angle = resolve_unit([header[idx["yaw"]]], units[1], ANGLE_RAD, "angle", UNITS_OPTION, what)
    bad = 0
    for c, (p, v) in enumerate(PAIRS):
        if p not in given:
            continue
        f = ANGLE_RAD[angle] if p == "yaw" else LENGTH_M[length]
        pos[:, c], qp[:, c], b1 = _column(rows, idx[p], header[idx[p]], p)
        vel[:, c], qv[:, c], b2 = _column(rows, idx[v], header[idx[v]], v)
        bad += b1 + b2
        moves = np.nan_to_num(np.diff(pos[:, c])) != 0
        if moves.any() and not (np.nan_to_num(vel[:, c]) != 0).any():
            raise UserError(f"{OPTION}: column {header[idx[v]]!r} ({v}) is 0 in every row while "
                            f"{header[idx[p]]!r} moves: it is not its finite difference")
        pos[:, c], qp[:, c], vel[:, c], qv[:, c] = pos[:, c] * f, qp[:, c] * f, vel[:, c] * f, qv[:, c] * f
    try:
        iv = intervals_from_velocities(pos, vel, qp, qv)
    except ValueError as exc:
        raise UserError(f"{what}: {OPTION}: {exc}") from None
    det, dis = int((iv.status == DETERMINED).sum()), int((iv.status == DISAGREE).sum())
    if dis > det:
        raise UserError(f"{what}: {OPTION}: the components give different intervals in {dis} of "
                        f"{det + dis} rows: the velocity columns are not finite differences of these "
                        "positions (other columns, or filtered velocities)")
    iv_units = {"length": length, "angle": angle}
    return iv, bad, {k: v for k, v in iv_units.items() if v}


def rebuild_time_base(text: str, spec: str, *, t_column: str, time_unit: str | None,
                      units: tuple[str | None, str | None] = (None, None), what: str = "file") -> TimeBase:
    """The rebuilt times of every data row of a CSV ``text`` (see the module doc).
    ``t_column``: the nominal time column (name or 1-based number), ``units``: the
    ``--time-from-units`` LENGTH, ANGLE."""
    cols = parse_time_from(spec)
    header, rows = read_table_text(text, what)
    if len(rows) < 2:
        raise UserError(f"{what}: {OPTION} needs two data rows or more")
    jt = column_index(header, t_column, "t", what)
    t_unit = resolve_unit([header[jt]], time_unit, TIME_S, "time", "--time-unit", what)
    idx = {k: column_index(header, c, k, what) for k, c in cols.items()}
    t_nom = np.empty(len(rows))
    for i, (ln, row) in enumerate(rows):
        t_nom[i] = parse_cell(row[jt] if jt < len(row) else "", f"{what}: line {ln}, column {jt + 1} ({header[jt]})")
        if math.isnan(t_nom[i]):
            raise UserError(f"{what}: line {ln}: the time cell ({header[jt]}) is empty")
    t_nom *= TIME_S[t_unit]
    if "dt" in cols:
        d_unit = resolve_unit([header[idx["dt"]]], time_unit, TIME_S, "time", "--time-unit", what)
        dt, _, bad = _column(rows, idx["dt"], header[idx["dt"]], "dt")
        try:
            iv = intervals_from_column(dt * TIME_S[d_unit])
        except ValueError:
            raise UserError(f"{what}: {OPTION}: column {header[idx['dt']]!r} holds no positive interval") from None
        src_units = {"time": d_unit}
    else:
        iv, bad, src_units = _velocity_intervals(rows, header, idx, cols, units, what)
    t = times_from(t_nom, iv)
    s = summary(t_nom, t, iv, header[jt])
    s.update(columns={k: header[j] for k, j in idx.items()}, units=src_units, bad_cells=bad)
    return TimeBase(t_nom, t, s)
