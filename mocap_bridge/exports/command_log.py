"""Valve and force logs as other labs write them, read into duty or wrench rows.

``--columns`` maps the file's columns: ``t`` (required) and either
- ``valves=COL``: one cell per row holding every valve's state, read ``--as``
  ``vector`` (``"[1, 0, 1, 0, 0, 0, 0, 0]"``: valve 1 first; the only form recognised
  without ``--as``), ``bitmask`` (an integer, bit i = valve i+1), ``hex`` (``0x05``: a
  bitmask in hexadecimal) or ``bits`` (``0x10100000``: one binary digit per valve, valve
  1 first, as some logs write a "hex" column that is not hex);
- ``d1=COL,...,dN=COL``: one column per valve, ``--as columns`` (0/1, on/off) or
  ``--as duty`` (PWM duty, percent);
- ``fx=COL,fy=COL,mz=COL``: force and torque, ``--as wrench`` (N, N m, or as ``--units``
  or the column names state).

Each row holds until the next (zero-order hold). The log's last row gets an end row one
median step later (the run-folder rule: the last row marks the end of the commanded span).
Time goes through the same unit rules as the pose columns (:mod:`.generic_csv`).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from common.errors import UserError
from mocap_bridge.exports.generic_csv import (
    TIME_S,
    column_index,
    read_table_text,
    resolve_unit,
)
from mocap_bridge.exports.table import parse_cell, time_factor

FORMS = ("vector", "bitmask", "hex", "bits", "columns", "duty", "wrench")
FORCE_N = {"n": 1.0, "mn": 1e-3}
MOMENT_NM = {"nm": 1.0, "n*m": 1.0, "n.m": 1.0, "mnm": 1e-3, "nmm": 1e-3}
_ON = {"1": 1, "1.0": 1, "true": 1, "on": 1, "0": 0, "0.0": 0, "false": 0, "off": 0}


def command_keys(n_valves: int) -> tuple[str, ...]:
    """The keys ``--columns`` takes for a command log of ``n_valves`` valves."""
    return ("t", "valves", *(f"d{i + 1}" for i in range(n_valves)), "fx", "fy", "mz")


@dataclass
class CommandTable:
    """Rows of a command log: ``t_s`` on the source's clock (seconds), ``values`` duty
    percent per valve (N, n) or the wrench ``fx, fy, mz`` (N, 3) in N, N m."""

    t_s: np.ndarray
    values: np.ndarray
    kind: str                     # "duty" or "wrench"
    counts: dict[str, int] = field(default_factory=dict)
    source: dict[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)


def _state(tok: str, where: str) -> int:
    v = _ON.get(tok.strip().lower())
    if v is None:
        raise UserError(f"{where}: valve state {tok.strip()!r} is not 0 or 1")
    return v


def parse_vector(cell: str, n: int, where: str) -> list[int]:
    """``"[1, 0, 1]"`` as ``[1, 0, 1]``; exactly ``n`` states of 0 or 1."""
    s = cell.strip()
    if not (s.startswith("[") and s.endswith("]")):
        raise UserError(f"{where}: {cell!r} is not a vector like [1, 0, ...]")
    toks = [t for t in re.split(r"[,\s]+", s[1:-1].strip()) if t]
    if len(toks) != n:
        raise UserError(f"{where}: {len(toks)} valve states in {cell!r}, the vehicle has {n} valves")
    return [_state(t, where) for t in toks]


def parse_mask(cell: str, n: int, form: str, where: str) -> list[int]:
    """A ``bitmask`` (decimal), ``hex`` or ``bits`` cell as ``n`` states (valve 1 first)."""
    s = cell.strip()
    try:
        if form == "bits":
            digits = s[2:] if s.lower().startswith("0x") else s
            if len(digits) != n or set(digits) - {"0", "1"}:
                raise ValueError
            return [int(d) for d in digits]
        value = int(s, 16) if form == "hex" else int(float(s)) if re.fullmatch(r"\d+(\.0*)?", s) else int(s)
    except ValueError:
        want = {"bits": f"{n} binary digits", "hex": "a hexadecimal number", "bitmask": "an integer"}[form]
        raise UserError(f"{where}: {cell!r} is not {want} (--as {form})") from None
    if value < 0 or value >= 1 << n:
        raise UserError(f"{where}: {cell!r} sets bits beyond valve {n} (--as {form}: bit i is valve i+1)")
    return [(value >> i) & 1 for i in range(n)]


def _form(columns: dict[str, str], form: str | None, first_cell: str | None, n: int) -> str:
    if form is not None:
        if form not in FORMS:
            raise UserError(f"--as {form}: choose one of {', '.join(FORMS)}")
        return form
    if any(k in columns for k in ("fx", "fy", "mz")):
        return "wrench"
    if "valves" in columns and first_cell is not None and first_cell.strip().startswith("["):
        return "vector"
    what = "the valves column" if "valves" in columns else "per-valve columns"
    raise UserError(f"say how to read {what}: --as {'|'.join(FORMS)} (only a vector [1, 0, ...] is "
                    "recognised by itself)")


def read_command_log(text: str, columns: dict[str, str], *, n_valves: int | None, form: str | None = None,
                     time_unit: str | None = None, units: tuple[str | None, str | None] = (None, None),
                     what: str = "file", time_map: Callable[[np.ndarray], np.ndarray] | None = None
                     ) -> CommandTable:
    """The commands of a log (see the module doc). ``n_valves`` is required unless the
    log is a wrench. ``time_map``: the rows' source times (s) to a rebuilt clock
    (:mod:`.time_base`), before the rows are held and the end row placed."""
    if "t" not in columns:
        raise UserError("--columns: give the time column (t=COL)")
    header, rows = read_table_text(text, what)
    if not rows:
        raise UserError(f"{what}: no data rows")
    first = None
    if "valves" in columns:
        j = column_index(header, columns["valves"], "valves", what)
        first = rows[0][1][j] if j < len(rows[0][1]) else None
    form = _form(columns, form, first, n_valves or 0)
    if form == "wrench":
        keys = ["fx", "fy", "mz"]
    elif n_valves is None:
        raise UserError("give the number of valves: --vehicle FILE or --valves N")
    elif form in ("columns", "duty"):
        keys = [f"d{i + 1}" for i in range(n_valves)]
    else:
        keys = ["valves"]
    missing = [k for k in keys if k not in columns]
    if missing:
        raise UserError(f"--columns: --as {form} needs {', '.join(f'{k}=COL' for k in missing)}")
    extra = sorted(set(columns) - {"t", *keys})
    if extra:
        raise UserError(f"--columns: {', '.join(extra)} not used with --as {form}")
    idx = {k: column_index(header, columns[k], k, what) for k in ["t", *keys]}
    t_unit = resolve_unit([header[idx["t"]]], time_unit, TIME_S, "time", "--time-unit", what)
    scale = np.ones(len(keys))
    src_units: dict[str, str] = {"time": t_unit}
    if form == "wrench":
        fu = resolve_unit([header[idx["fx"]], header[idx["fy"]]], units[0], FORCE_N, "force", "--units", what)
        mu = resolve_unit([header[idx["mz"]]], units[1], MOMENT_NM, "moment", "--units", what)
        scale = np.array([FORCE_N[fu], FORCE_N[fu], MOMENT_NM[mu]])
        src_units.update(force=fu, moment=mu)
    t_list, vals = [], []
    for ln, row in rows:
        def cell(k: str, row=row, ln=ln) -> tuple[str, str]:
            j = idx[k]
            if j >= len(row):
                raise UserError(f"{what}: line {ln} has {len(row)} cells; column {header[j]!r} is missing")
            return row[j], f"{what}: line {ln}, column {j + 1} ({header[j]})"
        t = parse_cell(*cell("t"))
        if np.isnan(t):
            raise UserError(f"{what}: line {ln}: the time cell ({header[idx['t']]}) is empty")
        if form == "vector":
            c, where = cell("valves")
            v = [100.0 * s for s in parse_vector(c, n_valves, where)]
        elif form in ("bitmask", "hex", "bits"):
            c, where = cell("valves")
            v = [100.0 * s for s in parse_mask(c, n_valves, form, where)]
        elif form == "columns":
            v = [100.0 * _state(*cell(k)) for k in keys]
        else:
            v = []
            for k in keys:
                x = parse_cell(*cell(k))
                if np.isnan(x):
                    raise UserError(f"{cell(k)[1]}: empty or NaN")
                if form == "duty" and not 0.0 <= x <= 100.0:
                    raise UserError(f"{cell(k)[1]}: duty {x:g} % is outside 0..100")
                v.append(x)
        t_list.append(t)
        vals.append(v)
    t_s = np.array(t_list) * time_factor(t_unit)
    if time_map is not None:
        t_s = time_map(t_s)
    values = np.array(vals, float) * scale
    table = _hold_rows(t_s, values, what)
    table.kind = "wrench" if form == "wrench" else "duty"
    table.source = {"format": f"command-log/{form}", "columns": {k: header[idx[k]] for k in ["t", *keys]},
                    "units": src_units, "valves": n_valves if form != "wrench" else None}
    if form == "hex" and _all_bits([rows[i][1][idx["valves"]] for i in range(len(rows))], n_valves):
        table.warnings.append(f"every {header[idx['valves']]} value is 0x and {n_valves} binary digits: "
                              "if it is one digit per valve, read it with --as bits")
    return table


def _all_bits(cells: list[str], n: int | None) -> bool:
    return n is not None and all(re.fullmatch(rf"0[xX][01]{{{n}}}", c.strip()) for c in cells)


def _hold_rows(t_s: np.ndarray, values: np.ndarray, what: str) -> CommandTable:
    """Rows in time order: time that goes back is refused; a row at the same time as the
    previous one replaces it (``repeated``); an end row one median step after the last."""
    dt = np.diff(t_s)
    back = np.flatnonzero(dt < 0)
    if len(back):
        i = int(back[0]) + 1
        raise UserError(f"{what}: time goes back at data row {i + 1} ({t_s[i - 1]:.9g} s then {t_s[i]:.9g} s)")
    keep = np.concatenate([dt > 0, [True]])  # of equal times, the later row holds
    t_k, v_k = t_s[keep], values[keep]
    step = float(np.median(np.diff(t_k))) if len(t_k) > 1 else 0.0
    if step <= 0:
        raise UserError(f"{what}: one command time only; a log needs two rows to span time")
    t_out = np.append(t_k, t_k[-1] + step)
    v_out = np.vstack([v_k, v_k[-1:]])
    counts = {"rows": len(t_s), "kept": int(keep.sum()), "repeated": int((~keep).sum()), "end_row_step_s": step}
    return CommandTable(t_out, v_out, "", counts)


def shift_to_origin(table: CommandTable, t0_s: float) -> tuple[np.ndarray, np.ndarray, int]:
    """The rows on the run's clock (``t - t0_s``): rows before the origin are dropped but
    the one in force at the origin is kept, at t = 0. Returns ``(t, values, dropped)``."""
    t = table.t_s - t0_s
    before = np.flatnonzero(t <= 0)
    start = int(before[-1]) if len(before) else 0
    t, v = t[start:].copy(), table.values[start:]
    if len(before):
        t[0] = 0.0
    if len(t) < 2:
        raise UserError("every command row is before the first pose: the log and the poses do not overlap")
    return t, v, start
