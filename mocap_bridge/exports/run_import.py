"""Other labs' recordings into a run folder: the use cases behind ``tpods import poses`` and
``tpods import commands``, callable from a notebook.

:func:`import_poses` reads a pose export (Vicon, Motive, any CSV through a column map) and
writes ``RUN/poses.csv`` (t, x, y, psi in s, m, rad); :func:`import_commands` reads a valve
or force log and writes ``RUN/commands.csv`` (t, d1..dN: duty percent) or ``RUN/wrench.csv``
(t, fx, fy, mz in N, N m). Both write the vehicle file and ``run.json`` and fill the same
folder in either order: each file is written beside and renamed (an existing one only with
``force``), ``run.json`` is merged and replaced atomically, and both share one time origin,
``run.json``'s ``time_origin_s`` (the source time that is t = 0): the first import sets it,
the second shifts its rows by it. ``time_from`` rebuilds the true times of a file whose time
column is a nominal counter (:mod:`mocap_bridge.exports.run_time_base`). Each returns an
:class:`ImportResult` (the lines a command prints, the warnings); a user error raises
:class:`common.errors.UserError` and leaves no folder it created.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from common.command_rules import onoff_scale_problem
from common.csvtable import read_table
from common.errors import UserError, Warnings
from common.interval_jitter import interval_jitter, jitter_warning
from common.outputs import ResultFile, check_plain_folder, names_a_file
from common.runfolder import POSE_COLUMNS
from common.runwriter import CsvLog, command_columns, run_header, write_json_atomic
from common.tomlfile import read_bytes, read_toml
from common.vehicle import Vehicle
from mocap_bridge.exports import PoseOptions, read_poses
from mocap_bridge.exports.command_log import command_keys, read_command_log, shift_to_origin
from mocap_bridge.exports.generic_csv import POSE_KEYS, parse_column_map
from mocap_bridge.exports.run_time_base import describe_use, keep_time_base, time_map


@dataclass
class ImportResult:
    """What an import wrote: ``path`` (the file), ``lines`` (its report, one line each) and
    ``warnings`` (each naming its subject)."""

    path: Path
    lines: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=Warnings)


def read_text(path: str | Path) -> str:
    """A text file of any common encoding (UTF-16 with its BOM, UTF-8, else Latin-1)."""
    raw = read_bytes(path, "file", "it")
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
        return raw.decode("utf-16")
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        return raw.decode("latin-1")


def _run_folder(out: str | Path) -> Path:
    out = str(out)
    if out and names_a_file(out):
        raise UserError(f"--out {out} names a file; tpods import writes a run folder; give a folder name "
                        f"(without {Path(out).suffix})")
    run = check_plain_folder(out, "--out")
    run.mkdir(parents=True, exist_ok=True)
    return run


def _read_meta(run: Path) -> dict[str, Any] | None:
    f = run / "run.json"
    if not f.exists():
        return None
    try:
        meta = json.loads(f.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise UserError(f"{f}: not readable JSON ({exc}); move it away first") from None
    if not isinstance(meta, dict):
        raise UserError(f"{f}: not a JSON object; move it away first")
    return meta


def _write_csv(path: Path, columns: tuple[str, ...], rows, formats, force: bool) -> None:
    """``rows`` into ``path`` through the run writer (``CsvLog``), written beside, fsynced
    and renamed (``ResultFile``): a crash leaves the old file or the new one whole."""
    out = ResultFile(path, force=force, option="--out")
    with out.writing() as tmp, CsvLog(tmp, columns, formats, flush_every_s=None) as log:
        log.write_many(rows)
        log.flush()
        os.fsync(log.fh.fileno())  # on disk before the rename makes it the run's file


_OTHER_HALF = {"poses.csv": (("commands.csv", "commands_source"), ("wrench.csv", "commands_source")),
               "commands.csv": (("poses.csv", "source"),), "wrench.csv": (("poses.csv", "source"),)}
"""The files the other import of the same recording writes, and the run.json key that says
an import wrote them."""


def _check_other_half(run: Path, meta: dict | None, name: str) -> None:
    """Refuse to import beside the other half of a simulated run (its truth belongs to
    another body): two runs would be mixed in one folder. A recorded half (``tpods mocap
    record``'s poses) is the lab's own and may take an imported log beside it."""
    m = meta or {}
    simulated = m.get("kind") == "simulation" or "truth" in m or (run / "truth.csv").exists()
    for other, key in _OTHER_HALF[name]:
        if (run / other).exists() and not m.get(key) and simulated:
            raise UserError(f"{run / other} belongs to a simulated run (its truth is another "
                            f"body's): importing {name} beside it would mix two runs; choose "
                            "another --out")


def _without_previous_run(run: Path, meta: dict | None, name: str, warnings: list[str]) -> dict:
    """run.json's fields less what belongs to a previous run and no import writes: its
    ``truth`` (another body's), with truth.csv removed (said in ``warnings``)."""
    fields = dict(meta or {})
    gone = [k for k in ("truth",) if k in fields]
    for k in gone:
        del fields[k]
    if (run / "truth.csv").exists():
        (run / "truth.csv").unlink()
        gone.append("truth.csv")
    if gone:
        warnings.append(f"{run}: removed {', '.join(gone)} of the previous run (not "
                        f"written by this import of {name})")
    return fields


def _last_time(run: Path, *names: str) -> float | None:
    """The last time of the first of ``names`` that the run holds (its first column)."""
    for name in names:
        f = run / name
        if f.exists():
            return float(read_table(f, ("t",))[-1, 0])
    return None


def _check_onoff_scale(vehicle_path: str | Path, duty, source: str) -> None:
    """Refuse 0/1 states read as percent on a vehicle's on/off valves
    (:mod:`common.command_rules`), before anything is written."""
    v = Vehicle.load(vehicle_path)
    problem = onoff_scale_problem(duty, [i for i, t in enumerate(v.thrusters)
                                         if t.table is None and not t.dead])
    if problem is not None:
        raise UserError(f"{source}: {problem}")


def _origin(meta: dict[str, Any] | None, run: Path, other: str) -> float | None:
    """The run's time origin if the other import (``other``: its file) set it and is there."""
    if meta and "time_origin_s" in meta and (run / other).exists():
        return float(meta["time_origin_s"])
    return None


@contextlib.contextmanager
def _leaves_no_new_folder(out: str | Path | None) -> Iterator[None]:
    """A refused import leaves no ``out`` folder it created (an empty one is removed)."""
    path = Path(out) if out else None
    existed = path is None or path.exists()
    try:
        yield
    except BaseException:
        if not existed and path.is_dir() and not any(path.iterdir()):
            path.rmdir()
        raise


def import_poses(file: str | Path, out: str | Path, *, body: str | None = None,
                 columns: str | None = None, units: str | None = None,
                 time_unit: str | None = None, plane: str | None = None, yaw_sign: float = 1.0,
                 rotation: str | None = None, time_from: str | None = None,
                 time_from_units: str | None = None, force: bool = False,
                 on_warning: Callable[[str], object] | None = None) -> ImportResult:
    """Read a pose recording ``file`` and write ``out/poses.csv`` (t,x,y,psi in s, m, rad; t
    from the first kept frame) and ``out/run.json`` (kind import-poses, the source, the counts
    of skipped frames). The options are those of ``tpods import poses`` (``body``: the body
    of a file holding several; ``columns``/``units``/``time_unit``: a plain CSV's map and
    units; ``plane``, ``yaw_sign``, ``rotation``: the mocap axes; ``time_from``: rebuild
    nominal times); ``on_warning(line)`` hears each warning as it arises."""
    with _leaves_no_new_folder(out):
        return _import_poses(str(file), out, body, columns, units, time_unit, plane, yaw_sign,
                             rotation, time_from, time_from_units, force, Warnings(on_warning))


def _import_poses(file, out, body, columns, units, time_unit, plane, yaw_sign, rotation,
                  time_from, time_from_units, force, warnings: Warnings) -> ImportResult:
    run = _run_folder(out)
    if (run / "poses.csv").exists() and not force:
        raise UserError(f"{run / 'poses.csv'} already exists; add --force to replace it or choose another --out")
    _check_other_half(run, _read_meta(run), "poses.csv")
    opts = PoseOptions(body=body, columns=columns, units=units, time_unit=time_unit,
                       plane=plane, yaw_sign=yaw_sign, rotation=rotation)
    text = read_text(file)
    table = read_poses(text, opts, what=file)
    meta = _read_meta(run)
    t_col = parse_column_map(columns, POSE_KEYS).get("t") if columns else None
    tm = time_map(time_from, time_from_units, time_unit, file, text, t_col, run, meta, "poses.csv",
                  ("commands.csv", "wrench.csv"))
    if tm is not None:  # the source's times on the rebuilt clock
        t_src = tm(table.t_s + table.t0_source_s)
        table.t0_source_s, table.t_s = float(t_src[0]), t_src - t_src[0]
    origin = _origin(meta, run, "commands.csv")
    if origin is None:  # (an origin of exactly 0.0 is an origin: no `or` here)
        origin = _origin(meta, run, "wrench.csv")
    t = table.t_s
    before = 0
    if origin is not None:  # the commands came first: their origin holds
        t = table.t_s + table.t0_source_s - origin
        keep = t >= 0
        before = int((~keep).sum())
        if not keep.any():
            raise UserError(f"{file}: every pose is before the commands' first row: the "
                            "poses and the commands do not overlap in time")
        end = _last_time(run, "commands.csv", "wrench.csv")
        if end is not None and float(np.min(t[keep])) > end:
            raise UserError(f"{file}: every pose is after the commands' last row "
                            f"({end:g} s on the run's clock): the poses and the commands do not "
                            "overlap in time")
        t, table.x_m, table.y_m, table.psi_rad = t[keep], table.x_m[keep], table.y_m[keep], table.psi_rad[keep]
    else:
        origin = table.t0_source_s
    rows = np.column_stack([t, table.x_m, table.y_m, table.psi_rad])
    _write_csv(run / "poses.csv", POSE_COLUMNS, rows, "%.12g", force)
    counts = dict(table.counts, before_commands=before) if before else table.counts
    res = ImportResult(run / "poses.csv", warnings=warnings)
    fields = {**_without_previous_run(run, meta, "poses.csv", res.warnings), **run_header("import-poses")}
    fields.update(source={"file": file, **table.source}, counts=counts,
                  time_origin_s=origin, status="complete")
    jitter = interval_jitter(t) if tm is not None else None
    used = keep_time_base(tm, run, fields, "import-poses", file)
    if used is not None:
        fields["source"]["time_base"] = dict(used, jitter=jitter)
    write_json_atomic(run / "run.json", fields)
    if tm is not None:
        res.lines.append(describe_use(tm, run))
        if (w := jitter_warning(jitter)) is not None:
            res.warnings.append(f"{file}: {w}")
    src = table.source
    span = float(t[-1] - t[0]) if len(t) else 0.0
    res.lines.append(
        f"wrote {run / 'poses.csv'}: {len(t)} poses over {span:.3f} s ({src['format']}"
        f"{', body ' + src['body'] if src.get('body') else ''}; skipped {counts['occluded']} occluded, "
        f"{counts['repeated']} repeated{f', {before} before the commands' if before else ''} "
        f"of {counts['frames']} frames)")
    return res


def vehicle_thrusters(path: str | Path) -> list[str]:
    """The names of a vehicle file's thrusters, in order (command columns d1..dN): the file
    read and checked whole (:meth:`common.vehicle.Vehicle.load`), so a broken vehicle is
    refused before anything is imported."""
    return [t.name for t in Vehicle.load(path).thrusters]


def copy_vehicle(src: str | Path, run: Path, force: bool) -> None:
    """The vehicle file into ``RUN/vehicle.toml`` (beside and renamed) with the thrust tables
    it names; an identical copy is left as it is, a different one only replaced with
    ``force``."""
    dest = run / "vehicle.toml"
    data = Path(src).read_bytes()
    if dest.exists() and dest.read_bytes() == data:
        return
    out = ResultFile(dest, force=force, option="--out")
    with out.writing() as tmp:
        tmp.write_bytes(data)
    for th in read_toml(src, "vehicle file").get("thrusters", []):  # the thrust tables it names
        name = th.get("thrust_table") if isinstance(th, dict) else None
        if isinstance(name, str) and not Path(name).is_absolute() and (Path(src).parent / name).is_file():
            (run / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(Path(src).parent / name, run / name)


def import_commands(file: str | Path, out: str | Path, columns: str, *,
                    vehicle: str | Path | None = None, valves: int | None = None,
                    form: str | None = None, frame: str = "body", time_unit: str | None = None,
                    units: str | None = None, time_from: str | None = None,
                    time_from_units: str | None = None, force: bool = False,
                    on_warning: Callable[[str], object] | None = None) -> ImportResult:
    """Read a command log ``file`` and write ``out/commands.csv`` (t,d1..dN: duty percent, an
    on/off valve 0 or 100, in the vehicle's thruster order) or ``out/wrench.csv`` (t,fx,fy,mz
    in N, N m; its ``frame`` in run.json), each row held until the next; an end row one
    median step after the last. ``columns``: the column map (t=COL and valves=COL, d1..dN=COL,
    or fx,fy,mz); ``vehicle`` (copied into the run) or ``valves`` give the valve count;
    ``form``: how to read the valve cells. Times share the poses' origin when ``out``
    already holds the poses of the same recording. ``on_warning(line)`` hears each warning
    as it arises."""
    with _leaves_no_new_folder(out):
        return _import_commands(str(file), out, columns, vehicle, valves, form, frame, time_unit,
                                units, time_from, time_from_units, force, Warnings(on_warning))


def _import_commands(file, out, columns, vehicle, valves, form, frame, time_unit, units,
                     time_from, time_from_units, force, warnings: Warnings) -> ImportResult:
    names = vehicle_thrusters(vehicle) if vehicle else None
    n = len(names) if names else valves
    if n is not None and n < 1:
        raise UserError(f"--valves {n}: give at least one valve")
    wrench = form == "wrench" or any(k in columns.lower() for k in ("fx=", "fy=", "mz="))
    if n is None and not wrench:
        raise UserError("give the valves: --vehicle FILE (its [[thrusters]]) or --valves N")
    unit_pair = tuple((units or ",").split(",", 1)) if units else (None, None)
    run = _run_folder(out)
    column_map = parse_column_map(columns, command_keys(n or 0))
    text = read_text(file)
    meta = _read_meta(run)
    name = "wrench.csv" if wrench else "commands.csv"
    tm = time_map(time_from, time_from_units, time_unit, file, text, column_map.get("t"), run, meta,
                  name, ("poses.csv",))
    table = read_command_log(text, column_map, n_valves=n, form=form, time_unit=time_unit,
                             units=(unit_pair[0] or None, unit_pair[1] or None),
                             what=file, time_map=tm)
    name = "wrench.csv" if table.kind == "wrench" else "commands.csv"
    if vehicle and table.kind != "wrench":
        _check_onoff_scale(vehicle, table.values, file)
    if (run / name).exists() and not force:
        raise UserError(f"{run / name} already exists; add --force to replace it or choose another --out")
    _check_other_half(run, meta, name)
    origin = _origin(meta, run, "poses.csv")
    if origin is None:
        origin = float(table.t_s[0])
    t, v, dropped = shift_to_origin(table, origin)
    end = _last_time(run, "poses.csv")
    if end is not None and float(t[0]) > end:
        raise UserError(f"{file}: every command row is after the last pose ({end:g} s on "
                        "the run's clock): the log and the poses do not overlap in time")
    rows = np.column_stack([t, v])
    if vehicle:  # first: a different vehicle.toml there is refused before any file is written
        copy_vehicle(vehicle, run, force)
    if table.kind == "wrench":
        _write_csv(run / name, ("t", "fx", "fy", "mz"), rows, "%.12g", force)
    else:
        _write_csv(run / name, command_columns(v.shape[1]), rows, ["%.9g"] + ["%.6g"] * v.shape[1], force)
    res = ImportResult(run / name, warnings=warnings)
    fields = (_without_previous_run(run, meta, name, res.warnings) if meta is not None
              else run_header("import-commands", status="complete"))
    fields["commands_source"] = {"file": file, **table.source,
                                 **({"vehicle": str(vehicle), "thrusters": names} if names else {})}
    fields["commands_counts"] = dict(table.counts, before_poses=dropped)
    fields.setdefault("time_origin_s", origin)
    if table.kind == "wrench":
        fields["wrench_frame"] = frame
    used = keep_time_base(tm, run, fields, "import-commands", file)
    if used is not None:
        fields["commands_source"]["time_base"] = used
    write_json_atomic(run / "run.json", fields)
    if tm is not None:
        res.lines.append(describe_use(tm, run))
    res.warnings += [f"{file}: {w}" for w in table.warnings]
    what = f"wrench in the {frame} frame" if table.kind == "wrench" else f"{v.shape[1]} valves"
    res.lines.append(
        f"wrote {run / name}: {len(t) - 1} rows and an end row at {t[-1]:.6g} s ({table.source['format']}, "
        f"{what}; {table.counts['repeated']} repeated times merged, {dropped} rows before the poses dropped)")
    return res
