"""Run folders: the on-disk contract between recorders, simulators and estimators.

A run is a folder holding (see docs/run-format.md):

- ``commands.csv``  ``t,d1,d2,d3,d4``: duty percent per thruster, zero-order hold;
  the last row marks the end of the commanded span.
- ``thrusts.csv``   optional ``t,T1,T2,T3,T4`` in newtons, same hold rule; used
  instead of commands.csv + thrust table when present.
- ``wrench.csv``    optional ``t,fx,fy,mz`` (N, N, N m about the tracked origin), same
  hold rule, frame in run.json ``wrench_frame`` (``body`` default, or ``lab``): the
  realised wrench replaces commands and thrust model (:mod:`common.wrench_input`).
- ``poses.csv``     ``t,x,y,psi``: metres and radians, lab frame; psi may be wrapped.
- ``run.json``      optional metadata (truth for simulated runs; a recorder's ``status``).
- ``structure.toml`` optional: the run is a structure run (:mod:`common.structure`):
  commands.csv holds ``t,d1..d{4N}`` (module 1's four duties, then module 2's, ...),
  thrusts.csv ``t,T1..T{4N}``, and poses.csv is the tracked structure frame.
- ``vehicle.toml`` optional: the run is a vehicle run (:mod:`common.vehicle`), read as a
  structure run is: commands.csv ``t,d1..dN`` in the vehicle's thruster order. Every reader
  below takes a Vehicle wherever it takes a Structure (``Run.structure``).

Readers validate and refuse bad input with one :class:`UserError` line naming the
file and the row. A run whose ``run.json`` (or, for a body folder of ``tpods mocap
record``, the ``recording.json`` above it) has a ``status`` other than ``complete`` or
``success`` is partial (:func:`partial_status`): it is read, with one warning line on
stderr naming the folder and the status (:func:`warn_if_partial`).

Writers (:func:`write_run` here, the recorders) write through
``common.runwriter`` (CSV logs flushed per row, atomic JSON, one JSON policy).
"""

from __future__ import annotations

import json
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from common.csvtable import read_table, read_table_lines  # noqa: F401  (re-exported)
from common.errors import UserError
from common.layout_files import as_layout, folder_layout
from common.plausible import check_duty_rows, check_pose_rows
from common.runwriter import CsvLog, command_columns, write_json_atomic
from common.structure import Structure
from common.thrust_table import load_thrust_table
from common.thrust_uncertainty import ThrustSensitivity, thrust_sensitivity
from common.vehicle import Vehicle
from common.wrench_input import WRENCH_COLUMNS, wrench_frame, wrench_thrusts

COMMAND_COLUMNS = ("t", "d1", "d2", "d3", "d4")
THRUST_COLUMNS = ("t", "T1", "T2", "T3", "T4")
POSE_COLUMNS = ("t", "x", "y", "psi")

# run.json ``status``: a recorder writes ``running`` when it starts and its final status
# when it ends. Only these mean it ended cleanly; any other status marks a partial run
# (docs/run-format.md). A run.json without status (simulated runs) is whole.
WHOLE_STATUSES = ("complete", "success")
_STATUS_MEANING = {
    "running": "the recorder never finished: it was killed, crashed or still runs",
    "incomplete": "the recording ended early",
    "aborted": "interrupted (Ctrl-C, SIGTERM or a stop) before the end",
    "stopped": "stopped (Ctrl-C or SIGTERM) before the end of the run",
    "failed": "the recording failed",
}


@dataclass
class Run:
    """A loaded run folder (arrays in SI units).

    Attributes:
        path: the folder.
        cmd_t: (Nc,) command switch times, s.
        duty_pct: (Nc, 4) duty per thruster, percent, or None if only thrusts.csv exists.
        thrust_n: (Nc', 4) thrusts, N, from thrusts.csv, or None.
        thrust_t: (Nc',) times of thrust_n rows, or None.
        pose_t: (N,) pose times, s.
        pose: (N, 3) x (m), y (m), psi (rad, as recorded: may be wrapped).
        meta: run.json contents ({} when absent).
        structure: the structure of a structure run (``structure.toml`` in the folder or
            given to :func:`read_run`), else None. Then duty_pct is (Nc, 4N) and
            thrust_n (Nc', 4N), module 1's four channels first. A vehicle run's
            :class:`common.vehicle.Vehicle` goes here too (duty_pct (Nc, N)).
        wrench_frame: ``body`` or ``lab`` for a wrench run (wrench.csv), else None: then
            thrust_t, thrust_n are the VIRTUAL thrusts of its body-frame wrench
            (:func:`common.wrench_input.wrench_thrusts`), whatever the structure.
    """

    path: Path
    cmd_t: np.ndarray
    duty_pct: np.ndarray | None
    pose_t: np.ndarray
    pose: np.ndarray
    thrust_t: np.ndarray | None = None
    thrust_n: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    structure: Structure | Vehicle | None = None
    wrench_frame: str | None = None

    @property
    def truth(self) -> dict[str, Any] | None:
        """The simulator's truth block from run.json, if any."""
        return self.meta.get("truth")

    def thrust_profile(self, table=None, clamp: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Switch times (Nc,) and thrusts (Nc, 4) in newtons: what the plant takes.

        thrusts.csv wins when present; otherwise commands.csv is mapped through
        ``table`` (default: the paper's Table 2). For a structure run the thrusts are the
        structure's VIRTUAL thrusts (:meth:`common.structure.Structure.virtual_thrust`:
        one module at the tracked origin with the structure's wrench; may be negative),
        and ``table``, when given, replaces the default Table 2 for the modules whose
        entry names no ``thrust_table`` (modules with their own table keep it).
        """
        if self.wrench_frame is not None:
            return self.thrust_t, self.thrust_n
        if self.structure is not None:
            s = self.structure_for(table)
            if self.thrust_n is not None:
                return self.thrust_t, s.virtual_from_thrust(self.thrust_n)
            try:
                return s.input_profile(self.cmd_t, self.duty_pct, clamp=clamp)
            except UserError as exc:
                raise UserError(f"{self.path / 'commands.csv'}: {exc}") from None
        if self.thrust_n is not None:
            return self.thrust_t, self.thrust_n
        table = table if table is not None else load_thrust_table(None)
        try:
            return self.cmd_t, table.thrust_n(self.duty_pct, clamp=clamp)
        except UserError as exc:
            raise UserError(f"{self.path / 'commands.csv'}: {exc}") from None

    def structure_for(self, table=None) -> Structure | None:
        """The run's structure with ``table`` for the modules without their own (None:
        as read), or None for a single-module run."""
        if self.structure is None or table is None:
            return self.structure
        return self.structure.with_table(table)

    def thrust_sensitivity(self, table=None, clamp: bool = False) -> ThrustSensitivity | None:
        """The thrust table's uncertainty at this run's commands (the consider input):
        :func:`common.thrust_uncertainty.thrust_sensitivity` of ``table`` (default Table 2),
        or for a structure or vehicle run every table's (and valve force's), mapped to the
        virtual thrusts (:meth:`common.structure.Structure.virtual_sensitivity`) on the rows
        of :meth:`thrust_profile`. None when thrusts.csv gives the thrusts or no table
        states an uncertainty."""
        return self.input_sensitivity(table, clamp)[1]

    def input_sensitivity(self, table=None, clamp: bool = False
                          ) -> tuple[np.ndarray, ThrustSensitivity | None]:
        """``(times, sensitivity)``: :meth:`thrust_sensitivity` with the times of its rows
        (the command times, or a vehicle's valve-timed rows of :meth:`thrust_profile`)."""
        if self.thrust_n is not None:
            return self.thrust_t, None
        try:
            if self.structure is not None:
                s = self.structure_for(table)
                if not s.states_uncertainty:
                    return self.cmd_t, None
                return s.input_sensitivity(self.cmd_t, self.duty_pct, clamp=clamp)
            table = table if table is not None else load_thrust_table(None)
            return self.cmd_t, (thrust_sensitivity(table, self.duty_pct, clamp=clamp)
                                if table.states_uncertainty else None)
        except UserError as exc:
            raise UserError(f"{self.path / 'commands.csv'}: {exc}") from None

    def window(self, t0: float | None, t1: float | None) -> Run:
        """A copy restricted to poses in [t0, t1] (commands are kept whole)."""
        lo = -math.inf if t0 is None else t0
        hi = math.inf if t1 is None else t1
        keep = (self.pose_t >= lo) & (self.pose_t <= hi)
        if keep.sum() < 2:
            raise UserError(f"{self.path}: window {t0}:{t1} holds fewer than 2 poses")
        return Run(self.path, self.cmd_t, self.duty_pct, self.pose_t[keep], self.pose[keep],
                   self.thrust_t, self.thrust_n, self.meta, self.structure, self.wrench_frame)


def read_run(path: str | Path, structure: Structure | Vehicle | str | Path | None = None) -> Run:
    """Load and validate a run folder.

    ``structure`` (a :class:`common.structure.Structure`, a :class:`common.vehicle.Vehicle`
    or its TOML file) makes it a structure (vehicle) run; without it, a ``structure.toml``
    (``vehicle.toml``) in the folder does. A structure run's
    commands.csv needs ``t,d1..d{4N}`` (thrusts.csv ``t,T1..T{4N}``); an explicit
    ``structure`` wins over the folder's file.
    """
    path = Path(path)
    if not path.is_dir():
        raise UserError(f"{path}: run folder not found")
    if structure is None:
        structure = folder_layout(path)
    structure = as_layout(structure)
    cmd_cols = COMMAND_COLUMNS if structure is None else structure.command_columns()
    thrust_cols = THRUST_COLUMNS if structure is None else structure.thrust_columns()
    thrust_file = path / "thrusts.csv"
    cmd_file = path / "commands.csv"
    wrench_file = path / "wrench.csv"
    thrust_t = thrust_n = None
    duty = None
    wrench = None
    if wrench_file.exists():
        if thrust_file.exists():
            raise UserError(f"{path}: holds both wrench.csv and thrusts.csv; a run's input is one "
                            "of them: remove one")
        wrench = read_table(wrench_file, WRENCH_COLUMNS)
        thrust_t = wrench[:, 0]
    elif thrust_file.exists():
        tv, tlines = read_table_lines(thrust_file, thrust_cols)
        thrust_t, thrust_n = tv[:, 0], tv[:, 1:]
        if np.any(thrust_n < 0):
            row = int(np.argwhere(thrust_n < 0)[0][0])
            raise UserError(f"{thrust_file}: line {tlines[row]}: negative thrust")
    if (cmd_file.exists() and wrench is None) or thrust_t is None:
        cv, clines = read_table_lines(cmd_file, cmd_cols)
        cmd_t, duty = cv[:, 0], cv[:, 1:]
        check_duty_rows(duty, clines, cmd_file)
        _check_commands_fit(cmd_file, duty, structure)
    else:
        cmd_t = thrust_t
    pv, plines = read_table_lines(path / "poses.csv", POSE_COLUMNS)
    pose_t, pose = pv[:, 0], pv[:, 1:]
    check_pose_rows(pose, plines, path / "poses.csv")
    span_t = thrust_t if thrust_t is not None else cmd_t
    span_name = ("commands.csv" if thrust_t is None else
                 "wrench.csv" if wrench is not None else "thrusts.csv")
    outside = (pose_t < span_t[0]) | (pose_t > span_t[-1])
    if outside.any():
        i = int(np.nonzero(outside)[0][0])
        raise UserError(
            f"{path / 'poses.csv'}: line {plines[i]}: pose time {pose_t[i]:g} s lies outside the commanded "
            f"span {span_t[0]:g}..{span_t[-1]:g} s of {span_name}")
    if len(pose_t) < 2:
        raise UserError(f"{path / 'poses.csv'}: need at least 2 poses")
    meta: dict[str, Any] = {}
    meta_file = path / "run.json"
    if meta_file.exists():
        try:
            meta = json.loads(meta_file.read_text(encoding="utf-8-sig"))  # Notepad may add a BOM
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise UserError(f"{meta_file}: not valid JSON ({exc})") from None
        if not isinstance(meta, dict):
            raise UserError(f"{meta_file}: must hold a JSON object")
        _check_truth(meta_file, meta.get("truth"))
        warn_if_partial(path, meta)
        warn_if_mixed_clock(path, meta)
    else:
        warn_if_partial(path)  # a body folder of a mocap recording
    frame = None
    if wrench is not None:
        frame = wrench_frame(meta, str(meta_file))
        thrust_t, thrust_n = wrench_thrusts(wrench[:, 0], wrench[:, 1:], frame, pose_t, pose[:, 2])
        cmd_t = thrust_t
    return Run(path, cmd_t, duty, pose_t, pose, thrust_t, thrust_n, meta, structure, frame)


def _check_commands_fit(cmd_file: Path, duty: np.ndarray, structure) -> None:
    """:mod:`common.command_rules` on a run's commands: no duty column beyond its vehicle's
    valves, and on/off valves in percent (UserError naming the file)."""
    from common.command_rules import columns_problem, onoff_scale_problem
    from common.csvtable import header_of

    n = len(cmd_cols_of(structure)) - 1
    what = ("the TPODS module" if structure is None else
            f"{structure.kind} {getattr(structure, 'name', '')}".strip())
    problem = columns_problem(header_of(cmd_file), n, what)
    if problem is None and getattr(structure, "kind", None) == "vehicle":
        problem = onoff_scale_problem(duty, [i for i, t in enumerate(structure.thrusters)
                                             if t.table is None and not t.dead])
    if problem is not None:
        raise UserError(f"{cmd_file}: {problem}")


def cmd_cols_of(structure) -> tuple[str, ...]:
    return COMMAND_COLUMNS if structure is None else structure.command_columns()


def _check_truth(meta_file: Path, truth: Any) -> None:
    """A ``truth`` block readers use must hold finite numbers (a null mass ended
    in a TypeError traceback)."""
    if truth is None:
        return
    if not isinstance(truth, dict):
        raise UserError(f"{meta_file}: truth must be a JSON object")
    for key in ("mass_kg", "izz_kgm2", "arm_m", "ct", "cr", "kb", "ax", "ay"):
        v = truth.get(key, 0.0)
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise UserError(f"{meta_file}: truth.{key} must be a finite number, got {v!r}")
    s0 = truth.get("initial_state")
    if s0 is not None and (not isinstance(s0, list) or len(s0) != 6 or not all(
            isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) for v in s0)):
        raise UserError(f"{meta_file}: truth.initial_state must be 6 finite numbers, got {s0!r}")


def partial_status(meta: Any) -> str | None:
    """The ``status`` of run metadata that marks its run partial, None for a whole run
    (status ``complete`` or ``success``, or no status at all, or ``running`` with
    ``data_complete: true``: a live estimator that has sealed its data files and still
    computes its final estimate, :meth:`estimator.live.recorder.LiveRecorder.seal`)."""
    status = meta.get("status") if isinstance(meta, dict) else None
    if status is None or str(status) in WHOLE_STATUSES:
        return None
    if str(status) == "running" and meta.get("data_complete") is True:
        return None
    return str(status)


def _status_file_meta(path: Path) -> tuple[Path, Any] | None:
    """(file, metadata) of the status file of a folder: its run.json, else the
    recording.json of the mocap recording it is a body folder of. Unreadable: None."""
    for f in (path / "run.json", path.parent / "recording.json"):
        if f.is_file():
            try:
                return f, json.loads(f.read_text(encoding="utf-8-sig"))
            except (OSError, ValueError):
                return None
    return None


def warn_if_partial(path: str | Path, meta: Any = None, *, source: str | Path | None = None) -> str | None:
    """Print one warning line on stderr if the run at ``path`` is partial; return its status.

    ``meta`` is its run.json as read (None: read ``path``'s status file here, see
    :func:`_status_file_meta`); ``source`` names the file the status came from."""
    if meta is None:
        found = _status_file_meta(Path(path))
        if found is None:
            return None
        source, meta = found
    status = partial_status(meta)
    if status is None:
        return None
    why = _STATUS_MEANING.get(status, "not a clean end")
    src = source if source is not None else Path(path) / "run.json"
    print(f"tpods: warning: {path} is a partial run ({src} says status {status!r}: {why}); "
          "reading what it holds", file=sys.stderr)
    return status


def warn_if_mixed_clock(path: str | Path, meta: Any) -> str | None:
    """Print one warning line on stderr if the live estimator that recorded the run applied
    a measured clock offset part-way through (run.json ``final.clock_offset_applied``): the
    poses before that moment keep the mocap host's clock, those after are corrected. Returns
    the line (None: nothing to say)."""
    final = meta.get("final") if isinstance(meta, dict) else None
    applied = final.get("clock_offset_applied") if isinstance(final, dict) else None
    if not isinstance(applied, dict):
        return None
    try:
        offset_ms = float(applied["offset_ms"])
        at = float(applied["from_pose_t_s"]) - float(meta.get("t0_lab") or 0.0)
    except (KeyError, TypeError, ValueError):
        return None
    line = (f"tpods: warning: {path}: the live estimator applied a clock offset of "
            f"{offset_ms:+.2f} ms to the poses from t = {at:.3f} s on; the poses before keep "
            f"the mocap host's clock (a step of {abs(offset_ms):.2f} ms in the pose times): "
            f"fit either side alone (--window 0:{at:.3f} or --window {at:.3f}:END)")
    print(line, file=sys.stderr)
    return line


def _write_csv(path: Path, columns: tuple[str, ...], t: np.ndarray, values: np.ndarray) -> None:
    data = np.column_stack([np.asarray(t, float), np.asarray(values, float)])
    with CsvLog(path, columns, "%.12g", flush_every_s=None) as log:
        log.write_many(data)


def write_run(path: str | Path, *, cmd_t=None, duty_pct=None, pose_t, pose, thrust_t=None,
              thrust_n=None, meta: dict[str, Any] | None = None,
              structure: Structure | Vehicle | None = None) -> Path:
    """Write a run folder (creating it): CSVs with 12 significant digits, run.json
    atomically with the toolkit's JSON policy (``common.runwriter``). Returns the folder.
    commands.csv/thrusts.csv get one column per channel of ``duty_pct``/``thrust_n``
    (``d1..d{4N}`` for a structure's 4N channels). With ``structure`` the folder also
    gets its ``structure.toml`` (and the modules' own tables), or a vehicle's
    ``vehicle.toml``."""
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    n_cmd = 4 if duty_pct is None else np.shape(duty_pct)[-1]
    n_thr = 4 if thrust_n is None else np.shape(thrust_n)[-1]
    if structure is not None and duty_pct is not None and n_cmd != structure.n_channels:
        raise ValueError(f"{n_cmd} duty columns for a structure of {structure.n_channels} channels")
    cmd_cols = command_columns(n_cmd)
    thrust_cols = ("t",) + tuple(f"T{i}" for i in range(1, n_thr + 1))
    if structure is not None:
        structure.write(path)
    if duty_pct is not None:
        _write_csv(path / "commands.csv", cmd_cols, cmd_t, duty_pct)
    if thrust_n is not None:
        _write_csv(path / "thrusts.csv", thrust_cols, thrust_t, thrust_n)
    _write_csv(path / "poses.csv", POSE_COLUMNS, pose_t, pose)
    if meta is not None:
        write_json_atomic(path / "run.json", meta)
    return path


