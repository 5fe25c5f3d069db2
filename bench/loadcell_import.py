"""Load-cell CSV logs (an HX711 and the like, written by another bench's logger) as a thrust
session that ``tpods bench fit`` reads (the folder format of :mod:`bench.session`).

The log has one row per reading: a time, a force (or a mass reading, taken as gram-force or
kilogram-force) and the valves' state, given as

- ``bitmask``: an integer (decimal, or ``0x``/``0b`` prefixed), bit i set = valve i+1 open;
- ``vector``: one 0/1 per valve, ``"[1, 0, 1, 0]"``, ``1 0 1 0`` or ``1;0;1;0``;
- ``duty``: the duty in percent, one number (the valve under test, valve 1) or one per
  valve as a vector.

Rows are cut into windows where the valve state changes. A window with every valve closed
is a zero window (its first ``zero_settle_s`` are ``zero_settle``, the rest ``zero``); an
open window is a step (``settle`` for ``settle_s``, then ``dwell``). ``steps.csv`` follows
from :func:`bench.session.summarize_steps`, drift-corrected between the zeros around each
step, as for a session recorded on the balance.

As the balance driver treats the balance's lines: an empty force cell is not a reading
(skipped and counted, like a line that is not a weight), and a row whose phase names a tare
(``tare``, ``taring``, ...) is not the load (skipped and counted, like a tare line). Every
other cell must be a number: the first that is not is a UserError naming its line and column.

``raw.csv`` keeps the session's columns and adds ``d1..dN`` (each valve's duty, 100 for an
open on/off valve) and ``source_phase``; ``run.json`` says where the log came from and
whether it holds on/off pulses (``"valves": "on/off"``) or duty steps.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from common.csvlines import cell_number, read_csv_lines
from common.errors import UserError
from common.thrust_table import GF_TO_N

FORCE_UNITS = {"g": 1.0, "gf": 1.0, "kg": 1000.0, "kgf": 1000.0, "N": 1.0 / GF_TO_N,
               "mN": 1e-3 / GF_TO_N}
"""Gram-force per unit of the force column (a mass reading is a force in gf or kgf)."""
VALVE_FORMATS = ("bitmask", "vector", "duty")
TIME_UNITS = {"s": 1.0, "ms": 1e-3}
DEFAULT_COLUMNS = {"t": "t_s", "force": "weight_g", "valves": "bitmask", "phase": "phase"}
TARE = re.compile(r"\btar(e|ing)", re.IGNORECASE)


@dataclass
class ImportedLog:
    """The session tables of an imported log and what the import counted."""

    raw: pd.DataFrame
    n_valves: int
    on_off: bool
    counts: dict[str, int] = field(default_factory=dict)
    columns: dict[str, str] = field(default_factory=dict)


def parse_columns(text: str | None) -> dict[str, str]:
    """``t=COL,force=COL,valves=COL[,phase=COL]`` over the defaults (the logger of
    AevarOfjord/mpc-air-bearing-satellite: ``t_s,weight_g,bitmask,...,phase``)."""
    cols = dict(DEFAULT_COLUMNS)
    if not text:
        return cols
    for item in text.split(","):
        key, sep, val = item.partition("=")
        key, val = key.strip(), val.strip()
        if not sep or key not in DEFAULT_COLUMNS or not val:
            raise UserError(f"--columns: {item.strip()!r} is not one of t=COL, force=COL, "
                            "valves=COL, phase=COL")
        cols[key] = val
    return cols


def parse_valves(cell: str, fmt: str, where: str) -> list[float]:
    """One row's valve cell as each valve's duty in percent (index 0 = valve 1)."""
    c = cell.strip()
    if fmt == "bitmask":
        try:
            prefixed = c[:2].lower() in ("0x", "0b")
            mask = int(c, 0) if prefixed else int(float(c))
            if mask < 0 or (not prefixed and float(c) != mask):
                raise ValueError
        except (ValueError, OverflowError):
            raise UserError(f"{where}: {cell!r} is not a bitmask (a non-negative integer)") from None
        return [100.0 if mask >> i & 1 else 0.0 for i in range(max(1, mask.bit_length()))]
    items = [x for x in re.split(r"[\s,;]+", c.strip("[]() ")) if x]
    if not items:
        raise UserError(f"{where}: empty valve cell")
    vals = [cell_number(x, where) for x in items]
    if fmt == "vector":
        if any(v not in (0.0, 1.0) for v in vals):
            raise UserError(f"{where}: {cell!r}: a valve vector holds 0 or 1 per valve")
        return [100.0 * v for v in vals]
    if any(not 0.0 <= v <= 100.0 for v in vals):
        raise UserError(f"{where}: {cell!r}: a duty is 0-100 %")
    return vals


def _read_rows(path: Path) -> tuple[list[str], list[tuple[int, list[str]]]]:
    lines = read_csv_lines(path)
    if len(lines) < 2:
        raise UserError(f"{path}: no data rows")
    return [h.strip() for h in lines[0][1]], lines[1:]


def read_log(path: str | Path, columns: dict[str, str] | None = None, force_unit: str = "g",
             valves_as: str = "bitmask", time_unit: str = "s", settle_s: float = 1.0,
             zero_settle_s: float = 1.0) -> ImportedLog:
    """Read a load-cell log into the session's raw table (see the module's docstring)."""
    path = Path(path)
    cols = dict(DEFAULT_COLUMNS if columns is None else columns)
    if force_unit not in FORCE_UNITS:
        raise UserError(f"--force-unit must be one of {', '.join(FORCE_UNITS)}, not {force_unit!r}")
    if valves_as not in VALVE_FORMATS:
        raise UserError(f"--valves-as must be one of {', '.join(VALVE_FORMATS)}, not {valves_as!r}")
    if time_unit not in TIME_UNITS:
        raise UserError(f"--time-unit must be s or ms, not {time_unit!r}")
    header, rows = _read_rows(path)
    idx = {}
    for key in ("t", "force", "valves", "phase"):
        name = cols[key]
        if name in header:
            idx[key] = header.index(name)
        elif key != "phase" or (columns is not None and "phase" in columns
                                and columns["phase"] != DEFAULT_COLUMNS["phase"]):
            raise UserError(f"{path}: no column {name!r} for {key} (columns: {', '.join(header)}; "
                            f"name it with --columns {key}=COL)")
    t, force, duties, phase, lines = [], [], [], [], []
    n_empty = n_tare = 0
    for lineno, row in rows:
        if len(row) < len(header):
            raise UserError(f"{path}: line {lineno}: {len(row)} cells for {len(header)} columns")
        where = f"{path}: line {lineno}: column {{}}"
        ph = row[idx["phase"]].strip() if "phase" in idx else ""
        if ph and TARE.search(ph):
            n_tare += 1
            continue
        ti = cell_number(row[idx["t"]].strip(), where.format(cols["t"])) * TIME_UNITS[time_unit]
        d = parse_valves(row[idx["valves"]], valves_as, where.format(cols["valves"]))
        cell = row[idx["force"]].strip()
        f = math.nan if cell == "" else cell_number(cell, where.format(cols["force"])) * FORCE_UNITS[force_unit]
        n_empty += cell == ""
        if t and ti <= t[-1]:
            raise UserError(f"{where.format(cols['t'])}: time {ti:g} s does not increase "
                            f"(line before: {t[-1]:g} s)")
        t.append(ti)
        force.append(f)
        duties.append(d)
        phase.append(ph)
        lines.append(lineno)
    if not t:
        raise UserError(f"{path}: no data rows (every row is a tare)")
    n_valves = max(len(d) for d in duties)
    dm = np.zeros((len(t), n_valves))
    for i, d in enumerate(duties):
        dm[i, :len(d)] = d
    raw = segment(np.array(t), np.array(force), dm, settle_s, zero_settle_s)
    raw["source_phase"] = phase
    raw["line"] = lines
    raw = raw[np.isfinite(raw["reading_gf"].to_numpy())].reset_index(drop=True)
    if raw.empty:
        raise UserError(f"{path}: no force reading (column {cols['force']!r} is empty on every row)")
    on_off = bool(np.all(np.isin(dm, (0.0, 100.0))))
    return ImportedLog(raw, n_valves, on_off,
                       {"rows": len(rows), "readings": len(raw), "empty_force_cells": n_empty,
                        "tare_rows_skipped": n_tare},
                       {k: cols[k] for k in idx})


def segment(t_s: np.ndarray, reading_gf: np.ndarray, duties_pct: np.ndarray, settle_s: float,
            zero_settle_s: float) -> pd.DataFrame:
    """The session's raw table (``RAW_COLUMNS`` plus ``d1..dN``): windows cut where the
    valves' duties change; closed windows are zeros, open ones steps."""
    change = np.r_[True, np.any(duties_pct[1:] != duties_pct[:-1], axis=1)]
    window = np.cumsum(change) - 1
    start = t_s[change][window]
    n_open = (duties_pct > 0).sum(axis=1)
    is_open = n_open > 0
    step = np.where(is_open, np.cumsum(change & is_open) - 1, -1)
    age = t_s - start
    phase = np.where(is_open, np.where(age < settle_s, "settle", "dwell"),
                     np.where(age < zero_settle_s, "zero_settle", "zero"))
    duty = np.where(is_open, duties_pct.max(axis=1), 0.0)
    out = pd.DataFrame({"t_s": t_s, "window": window, "phase": phase, "step": step,
                        "n_open": n_open, "duty_pct": duty, "reading_gf": reading_gf,
                        "stable": 1})
    for i in range(duties_pct.shape[1]):
        out[f"d{i + 1}"] = duties_pct[:, i]
    return out


def session_meta(log: ImportedLog, source: str, options: dict[str, Any]) -> dict[str, Any]:
    """The run.json fields of an imported session (after :func:`common.runwriter.run_header`)."""
    return {"status": "success", "imported_from": source, "import": options,
            "valves": "on/off" if log.on_off else "duty", "n_valves": log.n_valves,
            "columns": log.columns, "counts": log.counts}


def import_session(file: str | Path, out: str | Path, *, columns: str | None = None,
                   force_unit: str = "g", valves_as: str = "bitmask", time_unit: str = "s",
                   settle: float = 1.0, zero_settle: float = 1.0,
                   force: bool = False) -> list[str]:
    """The use case behind ``tpods bench import``: the log ``file`` into the session folder
    ``out`` (raw.csv, steps.csv, run.json; replaced only with ``force``); ``columns``: the
    column names (t=COL,force=COL,valves=COL[,phase=COL]); ``settle``, ``zero_settle``: s
    left out after a valve opens or the valves close. Returns the report's lines."""
    from bench.session import summarize_steps
    from common.outputs import ResultFolder
    from common.runwriter import run_header, write_json_atomic

    dest = ResultFolder(str(out), force=force, command="tpods bench import")
    log = read_log(file, parse_columns(columns), force_unit, valves_as, time_unit, settle,
                   zero_settle)
    steps = summarize_steps(log.raw)
    if steps.empty:
        raise UserError(f"{file}: no valve stayed open past --settle {settle:g} s: no step to fit")
    options = {"columns": columns, "force_unit": force_unit, "valves_as": valves_as,
               "time_unit": time_unit, "settle_s": settle, "zero_settle_s": zero_settle}
    meta = run_header("thrust-characterisation", **session_meta(log, str(file), options))
    with dest.writing() as d:
        log.raw.to_csv(d / "raw.csv", index=False, float_format="%.10g")
        steps.to_csv(d / "steps.csv", index=False)
        write_json_atomic(d / "run.json", meta)
    c = log.counts
    kind = "on/off pulses" if log.on_off else "duty steps"
    return [f"imported {c['readings']} readings of {log.n_valves} valve(s) as {kind}: "
            f"{len(steps)} steps; {c['empty_force_cells']} empty force cell(s) and "
            f"{c['tare_rows_skipped']} tare row(s) skipped",
            f"wrote {dest.path}/raw.csv, steps.csv, run.json (fit it: tpods bench fit {dest.path})"]
