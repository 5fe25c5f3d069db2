"""The time base shared by the two imports of one recording into a run folder
(``--time-from``): the true row times of a log whose time column is a nominal counter.

The import given ``--time-from`` rebuilds every data row's time
(:mod:`mocap_bridge.exports.time_from`) and keeps the nominal -> rebuilt map as
``RUN/time_base.csv`` (``t_nominal,t``: source seconds, one row per data row) and
``run.json`` ``time_base`` (what was done: method, rows determined and filled, spans,
intervals). The other import of the same folder, in either order, maps its nominal times
through it (or rebuilds them with the same ``--time-from`` and must agree with it). An
import on nominal times beside a rebuilt one, or the reverse, is refused in one line
(:class:`common.errors.UserError`). Times in s; knots are 1-D arrays of equal length.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from common.errors import UserError
from common.outputs import ResultFile
from common.runwriter import CsvLog
from mocap_bridge.exports.detect import split_units
from mocap_bridge.exports.time_base import describe, map_times
from mocap_bridge.exports.time_from import rebuild_time_base

TIME_BASE_FILE = "time_base.csv"
AGREE_S = 1e-6
"""Largest difference (s) between a stored time base and one rebuilt again from the same rows."""


@dataclass
class TimeMap:
    """Nominal source times -> rebuilt source times, from this file or from the run folder."""

    knots_nominal: np.ndarray
    knots_rebuilt: np.ndarray
    info: dict[str, Any]
    new: bool
    outside: int = field(default=0)

    def __call__(self, t: np.ndarray) -> np.ndarray:
        out, self.outside = map_times(t, self.knots_nominal, self.knots_rebuilt)
        return out


def _stored(run: Path, meta: dict[str, Any] | None) -> TimeMap | None:
    tb = (meta or {}).get("time_base")
    f = run / TIME_BASE_FILE
    if not isinstance(tb, dict) or not f.exists():
        return None
    try:
        a = np.loadtxt(f, delimiter=",", skiprows=1, ndmin=2)
    except (OSError, ValueError) as exc:
        raise UserError(f"{f}: not readable ({exc}); import the poses again with --time-from") from None
    if a.shape[1] != 2 or len(a) < 2 or not np.isfinite(a).all():
        raise UserError(f"{f}: not two columns t_nominal,t of finite numbers; import the poses again with --time-from")
    return TimeMap(a[:, 0], a[:, 1], tb, new=False)


def time_map(time_from: str | None, time_from_units: str | None, time_unit: str | None, file: str,
             text: str, t_column: str | None, run: Path, meta: dict[str, Any] | None,
             this: str, others: tuple[str, ...]) -> TimeMap | None:
    """The time map this import (``this``: its file in RUN) uses, or None (nominal times).
    ``time_from``, ``time_from_units``, ``time_unit``: the import's ``--time-from`` options
    (None: not given); ``file``: the source file's name (for messages); ``others``: the other
    import's possible files in RUN."""
    stored = _stored(run, meta)
    other = next((run / o for o in others if (run / o).exists()), None)
    if time_from is None:
        if time_from_units is not None:
            raise UserError("--time-from-units: give --time-from too")
        return stored if stored is not None and other is not None else None
    if t_column is None:
        raise UserError("--time-from reads a plain CSV's columns: give --columns t=COL,... too")
    tb = rebuild_time_base(text, time_from, t_column=t_column, time_unit=time_unit,
                           units=split_units(time_from_units, "--time-from-units", "m,rad"), what=str(file))
    if other is not None and stored is None:
        again = ("the commands again after the poses (with --force): they then take the rebuilt times"
                 if this == "poses.csv" else "the poses again with the same --time-from (and --force) first")
        raise UserError(f"{other} was imported on the nominal times of its file; import {again}")
    if other is not None and stored is not None:
        inside = (tb.t_nominal >= stored.knots_nominal[0]) & (tb.t_nominal <= stored.knots_nominal[-1])
        gap = np.abs(stored(tb.t_nominal[inside]) - tb.t[inside])
        if not inside.any() or gap.max() > AGREE_S:
            worst = f"{gap.max():.3g} s apart" if inside.any() else "no common nominal time"
            raise UserError(f"{run / TIME_BASE_FILE} (rebuilt by {stored.info.get('set_by', 'an import')} from "
                            f"{stored.info.get('from', 'its file')}) and the times rebuilt here differ "
                            f"({worst}); import both with the same --time-from")
    return TimeMap(tb.t_nominal, tb.t, dict(tb.summary), new=True)


def keep_time_base(tm: TimeMap | None, run: Path, fields: dict[str, Any], set_by: str, file: str) -> dict[str, Any] | None:
    """Write ``RUN/time_base.csv`` of a new map and set (or, without a map, drop) run.json's
    ``time_base`` in ``fields``; returns what the import's source entry says of its times."""
    if tm is None:
        fields.pop("time_base", None)
        return None
    if not tm.new:
        return {"file": TIME_BASE_FILE, "mapped_through": True, "set_by": tm.info.get("set_by"),
                **({"outside": tm.outside} if tm.outside else {})}

    out = ResultFile(run / TIME_BASE_FILE, force=True, option="--out")
    with out.writing() as tmp, CsvLog(tmp, ("t_nominal", "t"), "%.17g", flush_every_s=None) as log:
        log.write_many(np.column_stack([tm.knots_nominal, tm.knots_rebuilt]))
        log.flush()
    fields["time_base"] = {**tm.info, "file": TIME_BASE_FILE, "set_by": set_by, "from": file}
    return {**tm.info, "file": TIME_BASE_FILE}


def describe_use(tm: TimeMap, run: Path) -> str:
    """The line an import prints of its time map."""
    if tm.new:
        return describe(tm.info)
    s = tm.info
    out = f"; {tm.outside} beyond its rows at its overall rate" if tm.outside else ""
    return (f"times mapped through {run / TIME_BASE_FILE} (rebuilt by {s.get('set_by')} from {s.get('from')}: "
            f"{s.get('rebuilt_span_s', float('nan')):.1f} s against the nominal "
            f"{s.get('nominal_span_s', float('nan')):.1f} s{out})")
