"""``tpods import poses|commands``: other labs' recordings as a run folder.

The parsing is :mod:`mocap_bridge.exports` (pure functions on text); this module reads the
file, writes ``poses.csv``, ``commands.csv`` or ``wrench.csv``, the vehicle file and
``run.json`` into ``--out RUN``, and prints one line per file. The two commands fill the
same folder in either order (poses, then the commands of the same recording): each file
is written beside and renamed (an existing one only with ``--force``), ``run.json`` is
merged and replaced atomically. Both share one time origin, ``run.json``'s
``time_origin_s`` (the source time that is t = 0): the first import sets it (the poses:
their first kept frame), the second shifts its rows by it. ``--time-from`` rebuilds the true times of a file whose
time column is a nominal counter (:mod:`tpods.cli.imports_time`); the other import maps its
nominal times through the same rebuilt clock.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
from pathlib import Path
from typing import Any

from common.errors import UserError
from common.outputs import add_force
from tpods.cli.imports_time import add_time_from, describe_use, keep_time_base, time_map
from tpods.cli.parser import command, group

_FORMS = ("vector", "bitmask", "hex", "bits", "columns", "duty", "wrench")


def register(sub) -> None:
    """Add the ``tpods import`` group."""
    g = group(sub, "import", "other labs' recordings (Vicon, Motive, CSV logs) as a run folder")
    p = command(
        g, "poses", cmd_import_poses,
        help="a Vicon/Motive export or any CSV as poses.csv of a run folder")
    p.add_argument("file", metavar="FILE", help="the export or CSV file")
    p.add_argument("--out", required=True, metavar="RUN", help="the run folder (created, or one that "
                   "already holds the commands of the same recording)")
    p.add_argument("--body", default=None, metavar="NAME",
                   help="the body (Vicon subject:segment or its part, Motive rigid body name) when "
                        "the file holds several")
    p.add_argument("--columns", default=None, metavar="MAP",
                   help="read FILE as a plain CSV: t=COL,x=COL,y=COL,yaw=COL (or z=, qx=,qy=,qz=,qw= "
                        "for a quaternion); COL is a header name or a 1-based number")
    p.add_argument("--units", default=None, metavar="LENGTH,ANGLE",
                   help="units the file does not state: m|cm|mm and rad|deg (e.g. mm,deg)")
    p.add_argument("--time-unit", default=None, metavar="s|ms",
                   help="the unit of the --columns time column, unless its name states it")
    p.add_argument("--plane", default=None, metavar="AB",
                   help="the mocap axes that are the table's x and y, each optionally signed: xy "
                        "(default for Vicon and --columns), x-z (default for Motive, Y-up), zx, ... "
                        "(a leading minus needs =: --plane=-yx)")
    p.add_argument("--yaw-sign", type=float, default=1.0, choices=(1.0, -1.0), metavar="1|-1",
                   help="multiply the yaw by -1 when the source turns the other way")
    p.add_argument("--rotation", default=None, metavar="KIND",
                   help="the rotation convention when the file does not say and the body tilts: "
                        "euler-xyz|helical (Vicon RX,RY,RZ), intrinsic|extrinsic (Motive Euler)")
    add_time_from(p, "poses")
    add_force(p, "RUN/poses.csv")

    c = command(
        g, "commands", cmd_import_commands,
        help="a valve or force log as commands.csv or wrench.csv of a run folder")
    c.add_argument("file", metavar="FILE", help="the log (CSV with a header line)")
    c.add_argument("--out", required=True, metavar="RUN", help="the run folder")
    who = c.add_mutually_exclusive_group()
    who.add_argument("--vehicle", default=None, metavar="FILE",
                     help="the vehicle file (vehicle.toml): its [[thrusters]] give the valve count "
                          "and order; copied into RUN")
    who.add_argument("--valves", type=int, default=None, metavar="N", help="the number of valves")
    c.add_argument("--columns", required=True, metavar="MAP",
                   help="t=COL and valves=COL (one cell per row), or d1=COL..dN=COL, or "
                        "fx=COL,fy=COL,mz=COL")
    c.add_argument("--as", dest="form", default=None, choices=_FORMS,
                   help="how to read the valve cells (a vector [1, 0, ...] is recognised by itself)")
    c.add_argument("--frame", default="body", choices=("body", "lab"),
                   help="the frame of a wrench (default body)")
    c.add_argument("--time-unit", default=None, metavar="s|ms",
                   help="the unit of the time column, unless its name states it")
    c.add_argument("--units", default=None, metavar="FORCE,MOMENT",
                   help="wrench units the column names do not state: N|mN and Nm|mNm")
    add_time_from(c, "commands")
    add_force(c, "RUN/commands.csv (wrench.csv)")


# ----------------------------------------------------------------------------- shared


def _read_text(path: str) -> str:
    from common.tomlfile import read_bytes

    raw = read_bytes(path, "file", "it")
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
        return raw.decode("utf-16")
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        return raw.decode("latin-1")


def _run_folder(out: str) -> Path:
    from common.outputs import check_plain_folder, names_a_file

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
    from common.outputs import ResultFile
    from common.runwriter import CsvLog

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


def _without_previous_run(run: Path, meta: dict | None, name: str) -> dict:
    """run.json's fields less what belongs to a previous run and no import writes: its
    ``truth`` (another body's), with truth.csv removed (said)."""
    fields = dict(meta or {})
    gone = [k for k in ("truth",) if k in fields]
    for k in gone:
        del fields[k]
    if (run / "truth.csv").exists():
        (run / "truth.csv").unlink()
        gone.append("truth.csv")
    if gone:
        print(f"tpods: warning: {run}: removed {', '.join(gone)} of the previous run (not "
              f"written by this import of {name})", file=sys.stderr)
    return fields


def _last_time(run: Path, *names: str) -> float | None:
    """The last time of the first of ``names`` that the run holds (its first column)."""
    for name in names:
        f = run / name
        if f.exists():
            from common.csvtable import read_table

            return float(read_table(f, ("t",))[-1, 0])
    return None


def _check_onoff_scale(vehicle_path: str, duty, source: str) -> None:
    """Refuse 0/1 states read as percent on a vehicle's on/off valves
    (:mod:`common.command_rules`), before anything is written."""
    from common.command_rules import onoff_scale_problem
    from common.vehicle import Vehicle

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


# ----------------------------------------------------------------------------- poses


def _leaves_no_new_folder(fn):
    """A refused import leaves no ``--out`` folder it created (an empty one is removed)."""
    import functools

    @functools.wraps(fn)
    def wrapper(args: argparse.Namespace) -> int:
        out = Path(args.out) if args.out else None
        existed = out is None or out.exists()
        try:
            return fn(args)
        except BaseException:
            if not existed and out.is_dir() and not any(out.iterdir()):
                out.rmdir()
            raise
    return wrapper


@_leaves_no_new_folder
def cmd_import_poses(args: argparse.Namespace) -> int:
    """Read a pose recording and write RUN/poses.csv (t,x,y,psi in s, m, rad; t from the first kept
    frame) and RUN/run.json (kind import-poses, the source, the counts of skipped frames). Vicon
    Tracker (Objects) and Nexus (Segments) CSV exports and OptiTrack Motive CSV exports are
    recognised from their header; any other CSV is read through --columns and --units. Occluded
    frames (empty or NaN cells) are skipped and counted; a bad cell is one error naming it."""

    import numpy as np

    from common.interval_jitter import interval_jitter, jitter_warning
    from common.runfolder import POSE_COLUMNS
    from common.runwriter import run_header, write_json_atomic
    from mocap_bridge.exports import PoseOptions, read_poses
    from mocap_bridge.exports.generic_csv import POSE_KEYS, parse_column_map

    run = _run_folder(args.out)
    if (run / "poses.csv").exists() and not args.force:
        raise UserError(f"{run / 'poses.csv'} already exists; add --force to replace it or choose another --out")
    _check_other_half(run, _read_meta(run), "poses.csv")
    opts = PoseOptions(body=args.body, columns=args.columns, units=args.units, time_unit=args.time_unit,
                       plane=args.plane, yaw_sign=args.yaw_sign, rotation=args.rotation)
    text = _read_text(args.file)
    table = read_poses(text, opts, what=args.file)
    meta = _read_meta(run)
    t_col = parse_column_map(args.columns, POSE_KEYS).get("t") if args.columns else None
    tm = time_map(args, text, t_col, run, meta, "poses.csv", ("commands.csv", "wrench.csv"))
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
            raise UserError(f"{args.file}: every pose is before the commands' first row: the "
                            "poses and the commands do not overlap in time")
        end = _last_time(run, "commands.csv", "wrench.csv")
        if end is not None and float(np.min(t[keep])) > end:
            raise UserError(f"{args.file}: every pose is after the commands' last row "
                            f"({end:g} s on the run's clock): the poses and the commands do not "
                            "overlap in time")
        t, table.x_m, table.y_m, table.psi_rad = t[keep], table.x_m[keep], table.y_m[keep], table.psi_rad[keep]
    else:
        origin = table.t0_source_s
    rows = np.column_stack([t, table.x_m, table.y_m, table.psi_rad])
    _write_csv(run / "poses.csv", POSE_COLUMNS, rows, "%.12g", args.force)
    counts = dict(table.counts, before_commands=before) if before else table.counts
    fields = {**_without_previous_run(run, meta, "poses.csv"), **run_header("import-poses")}
    fields.update(source={"file": str(args.file), **table.source}, counts=counts,
                  time_origin_s=origin, status="complete")
    jitter = interval_jitter(t) if tm is not None else None
    used = keep_time_base(tm, run, fields, "import-poses", str(args.file))
    if used is not None:
        fields["source"]["time_base"] = dict(used, jitter=jitter)
    write_json_atomic(run / "run.json", fields)
    if tm is not None:
        print(describe_use(tm, run))
        if (w := jitter_warning(jitter)) is not None:
            print(f"tpods: warning: {args.file}: {w}", file=sys.stderr)
    src = table.source
    span = float(t[-1] - t[0]) if len(t) else 0.0
    print(f"wrote {run / 'poses.csv'}: {len(t)} poses over {span:.3f} s ({src['format']}"
          f"{', body ' + src['body'] if src.get('body') else ''}; skipped {counts['occluded']} occluded, "
          f"{counts['repeated']} repeated{f', {before} before the commands' if before else ''} "
          f"of {counts['frames']} frames)")
    return 0


# ----------------------------------------------------------------------------- commands


def vehicle_thrusters(path: str | Path) -> list[str]:
    """The names of a vehicle file's thrusters, in order (command columns d1..dN): the file
    read and checked whole (:meth:`common.vehicle.Vehicle.load`), so a broken vehicle is
    refused before anything is imported."""
    from common.vehicle import Vehicle

    return [t.name for t in Vehicle.load(path).thrusters]


def _copy_vehicle(src: str, run: Path, force: bool) -> None:
    """The vehicle file into ``RUN/vehicle.toml`` (beside and renamed); an identical copy
    is left as it is, a different one only replaced with ``--force``."""
    from common.outputs import ResultFile
    from common.tomlfile import read_toml

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


@_leaves_no_new_folder
def cmd_import_commands(args: argparse.Namespace) -> int:
    """Read a command log and write RUN/commands.csv (t,d1..dN: duty percent, an on/off valve 0 or
    100, in the vehicle's thruster order) or RUN/wrench.csv (t,fx,fy,mz in N, N m; its frame in
    run.json), each row held until the next; an end row one median step after the last. Valve
    states are read as vectors "[1, 0, ...]", integer or hex bitmasks (bit i = valve i+1), bit
    strings, per-valve on/off or duty columns. Times share the poses' origin when RUN already
    holds the poses of the same recording."""

    from common.runwriter import command_columns, run_header, write_json_atomic
    from mocap_bridge.exports.command_log import command_keys, read_command_log, shift_to_origin
    from mocap_bridge.exports.generic_csv import parse_column_map

    names = vehicle_thrusters(args.vehicle) if args.vehicle else None
    n = len(names) if names else args.valves
    if n is not None and n < 1:
        raise UserError(f"--valves {n}: give at least one valve")
    wrench = args.form == "wrench" or any(k in args.columns.lower() for k in ("fx=", "fy=", "mz="))
    if n is None and not wrench:
        raise UserError("give the valves: --vehicle FILE (its [[thrusters]]) or --valves N")
    units = tuple((args.units or ",").split(",", 1)) if args.units else (None, None)
    run = _run_folder(args.out)
    columns = parse_column_map(args.columns, command_keys(n or 0))
    text = _read_text(args.file)
    meta = _read_meta(run)
    name = "wrench.csv" if wrench else "commands.csv"
    tm = time_map(args, text, columns.get("t"), run, meta, name, ("poses.csv",))
    table = read_command_log(text, columns, n_valves=n, form=args.form,
                             time_unit=args.time_unit, units=(units[0] or None, units[1] or None),
                             what=args.file, time_map=tm)
    name = "wrench.csv" if table.kind == "wrench" else "commands.csv"
    if args.vehicle and table.kind != "wrench":
        _check_onoff_scale(args.vehicle, table.values, args.file)
    if (run / name).exists() and not args.force:
        raise UserError(f"{run / name} already exists; add --force to replace it or choose another --out")
    _check_other_half(run, meta, name)
    origin = _origin(meta, run, "poses.csv")
    if origin is None:
        origin = float(table.t_s[0])
    t, v, dropped = shift_to_origin(table, origin)
    end = _last_time(run, "poses.csv")
    if end is not None and float(t[0]) > end:
        raise UserError(f"{args.file}: every command row is after the last pose ({end:g} s on "
                        "the run's clock): the log and the poses do not overlap in time")
    import numpy as np

    rows = np.column_stack([t, v])
    if args.vehicle:  # first: a different vehicle.toml there is refused before any file is written
        _copy_vehicle(args.vehicle, run, args.force)
    if table.kind == "wrench":
        _write_csv(run / name, ("t", "fx", "fy", "mz"), rows, "%.12g", args.force)
    else:
        _write_csv(run / name, command_columns(v.shape[1]), rows, ["%.9g"] + ["%.6g"] * v.shape[1], args.force)
    fields = (_without_previous_run(run, meta, name) if meta is not None
              else run_header("import-commands", status="complete"))
    fields["commands_source"] = {"file": str(args.file), **table.source,
                                 **({"vehicle": str(args.vehicle), "thrusters": names} if names else {})}
    fields["commands_counts"] = dict(table.counts, before_poses=dropped)
    fields.setdefault("time_origin_s", origin)
    if table.kind == "wrench":
        fields["wrench_frame"] = args.frame
    used = keep_time_base(tm, run, fields, "import-commands", str(args.file))
    if used is not None:
        fields["commands_source"]["time_base"] = used
    write_json_atomic(run / "run.json", fields)
    if tm is not None:
        print(describe_use(tm, run))
    for w in table.warnings:
        print(f"tpods: warning: {args.file}: {w}", file=sys.stderr)
    what = f"wrench in the {args.frame} frame" if table.kind == "wrench" else f"{v.shape[1]} valves"
    print(f"wrote {run / name}: {len(t) - 1} rows and an end row at {t[-1]:.6g} s ({table.source['format']}, "
          f"{what}; {table.counts['repeated']} repeated times merged, {dropped} rows before the poses dropped)")
    return 0
