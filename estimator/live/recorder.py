"""The live estimator's run folder: what it saw, written as it goes (:mod:`common.runwriter`).

With ``--mcap`` (or ``--out X.mcap``) the streams themselves are recorded too:
:func:`record_streams` logs every message of the body's pose, command and estimate keys,
as received (the estimates: as published), into a :class:`common.mcap.log.McapLog`.
"""

from __future__ import annotations

import contextlib
import math
from pathlib import Path
from typing import Any

import numpy as np

from common.errors import UserError
from common.mcap.log import McapLog
from common.mcap.log import subscribe as _subscribe
from common.runwriter import CommandLog, CsvLog, write_json_atomic
from estimator.filters.ekf import STATE_NAMES

POSE_COLUMNS = ("t", "x", "y", "psi")
POSE_FORMATS = ("%.9f", "%.12g", "%.12g", "%.12g")
ESTIMATE_COLUMNS = ("t", "frame", "phase", "mass_kg", "mass_sigma_kg", "izz_kgm2", "izz_sigma_kgm2",
                    *STATE_NAMES[:6], *(f"sigma_{n}" for n in STATE_NAMES[:6]),
                    "mass_sigma_noise_kg", "mass_sigma_thrust_kg", "izz_sigma_noise_kgm2",
                    "izz_sigma_thrust_kgm2")
"""``mass_sigma_kg``/``izz_sigma_kgm2`` are the total (noise + thrust table); the parts last."""
ESTIMATE_FORMATS = ("%.9f", "%d", "%s", "%.10g", "%.6g", "%.10g", "%.6g",
                    *["%.10g"] * 6, *["%.6g"] * 6, *["%.6g"] * 4)
COM_COLUMNS = ("com_x_m", "com_x_sigma_m", "com_y_m", "com_y_sigma_m")
"""A structure's estimates.csv ends with these (centre of mass, tracked frame; total sigmas)."""
COM_FORMATS = ("%.10g", "%.6g", "%.10g", "%.6g")


class LiveRecorder:
    """What the live estimator saw, as a run folder written as it goes.

    - ``commands.csv``: every command received (``set``, ``hold``, ``end``; also those too
      late for the live filter) in arrival order, times from ``t0`` (the first command's
      lab time); flushed per row.
    - ``poses.csv``: the aligned poses the filter used, written as soon as a command
      row at or after them exists (so the folder is always a valid run: a kill loses
      at most the poses after the last command or hold message, 0.1 s by default).
    - ``estimates.csv``: the filter's mean and sigma after every update (flushed at most
      every ``flush_every_s``).
    - ``run.json``: settings, ``t0_lab``, status (``running`` until the end: left
      behind, it means the process died; then the live run's ``success``, ``stopped``,
      ``aborted`` or ``failed``), counters and the final estimate. Anything but
      ``success`` marks a partial run: readers warn (docs/run-format.md).
    - a structure (``structure``): ``structure.toml`` (self-contained) makes the
      folder a structure run; commands.csv has the merged ``d1..d{4N}``; estimates.csv
      ends with :data:`COM_COLUMNS`.
    """

    def __init__(self, out: str | Path, meta: dict[str, Any], n_channels: int = 4,
                 flush_every_s: float = 0.1, structure: Any = None) -> None:
        self.out = Path(out)
        try:
            self.out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise UserError(f"{self.out}: cannot create the output folder ({exc.strerror})") from None
        if (self.out / "poses.csv").exists():
            raise UserError(f"{self.out} already holds a run (poses.csv); choose another --out")
        self.meta = dict(meta)
        self.meta.setdefault("status", "running")
        self.t0: float | None = None
        self.structure = structure
        if structure is not None:
            n_channels = structure.n_channels
            structure.write(self.out)
        self.n_channels = n_channels
        self._cmd = CommandLog(self.out / "commands.csv", n_channels, t_format="%.9f")
        self._pose = CsvLog(self.out / "poses.csv", POSE_COLUMNS, POSE_FORMATS)
        cols, fmts = ESTIMATE_COLUMNS, ESTIMATE_FORMATS
        if structure is not None:
            cols, fmts = cols + COM_COLUMNS, fmts + COM_FORMATS
        self._est = CsvLog(self.out / "estimates.csv", cols, fmts, flush_every_s=flush_every_s)
        self.last_cmd_t = -math.inf
        self.last_duty: tuple[float, ...] | None = None
        self.last_pose_t = -math.inf
        self._pending: list[tuple[float, float, float, float]] = []
        self.counts = {"commands": 0, "commands_unrecorded": 0, "poses": 0, "estimates": 0}
        self.closed = False
        self.sealed = False
        """:meth:`seal` ran: commands.csv and poses.csv are closed and whole."""
        self.write_meta()

    def write_meta(self) -> None:
        self.meta["t0_lab"] = self.t0
        write_json_atomic(self.out / "run.json", self.meta)

    def command(self, t: float, duty) -> None:
        if self.sealed:  # after the end of the stream (none expected): not recorded
            self.counts["commands_unrecorded"] += 1
            return
        if self.t0 is None:
            self.t0 = t
            self.write_meta()
        if not t > self.last_cmd_t:
            self.counts["commands_unrecorded"] += 1
            return
        self._cmd.add(t - self.t0, duty)
        self.last_cmd_t = t
        self.last_duty = tuple(duty)
        self.counts["commands"] += 1
        self._write_covered()

    def pose(self, t: float, x: float, y: float, yaw: float) -> None:
        if self.sealed:
            return
        self._pending.append((t, x, y, yaw))
        self._write_covered()

    def _write_covered(self) -> None:
        if not self._pending or self.t0 is None:
            return
        n = 0
        rows = []
        for p in self._pending:
            if p[0] > self.last_cmd_t:
                break
            if p[0] > self.last_pose_t and p[0] >= self.t0:
                rows.append((p[0] - self.t0, p[1], p[2], p[3]))
                self.last_pose_t = p[0]
                self.counts["poses"] += 1
            n += 1
        if n:
            del self._pending[:n]
            self._pose.write_many(rows)

    def estimate(self, t: float, frame: int, phase: str, z: np.ndarray, sig: np.ndarray,
                 thrust_rel: tuple[float, float] = (0.0, 0.0),
                 com: tuple[float, float, float, float] | None = None) -> None:
        """One estimates.csv row; ``thrust_rel``: the thrust table's sigma as fractions of m
        and Izz (added in quadrature to the filter's noise sigma ``sig``); a structure's
        ``com``: (cx, its total sigma, cy, its total sigma), m."""
        t0 = self.t0 if self.t0 is not None else t
        tm, ti = abs(z[6]) * thrust_rel[0], abs(z[7]) * thrust_rel[1]
        if self.structure is None:
            com = ()
        elif com is None:
            com = (math.nan,) * 4
        self._est.write(t - t0, frame, phase, z[6], math.hypot(sig[6], tm), z[7],
                        math.hypot(sig[7], ti), *z[:6], *sig[:6], sig[6], tm, sig[7], ti, *com)
        self.counts["estimates"] += 1

    def seal(self) -> None:
        """The run's data are whole (the end of the stream, before the estimator's final
        fit): a last hold row covers the poses still pending, commands.csv and poses.csv
        are closed and run.json says ``data_complete: true`` with their row counts, its
        status still ``running``. Readers take such a folder as whole
        (:func:`common.runfolder.partial_status`): a post-processing fit can start while
        the estimator finishes (``tpods demo``). estimates.csv stays open until
        :meth:`close`."""
        if self.closed or self.sealed:
            return
        if self._pending and self.last_duty is not None:
            t_last = self._pending[-1][0]
            if t_last > self.last_cmd_t:
                self.command(t_last, self.last_duty)
        for log in (self._cmd, self._pose):
            with contextlib.suppress(OSError):
                log.close()
        self.sealed = True
        self.meta["data_complete"] = True
        self.meta["recorded"] = {k: self.counts[k] for k in ("commands", "commands_unrecorded",
                                                             "poses")}
        with contextlib.suppress(OSError):
            self.write_meta()

    def close(self, status: str, extra: dict[str, Any] | None = None) -> None:
        """Close the files: a last hold row covers the poses still pending; write ``status``
        (``success`` for a run that ended cleanly, anything else marks it partial)."""
        if self.closed:
            return
        self.closed = True
        if self._pending and self.last_duty is not None and not self.sealed:
            t_last = self._pending[-1][0]
            if t_last > self.last_cmd_t:
                self.command(t_last, self.last_duty)
        for log in (self._cmd, self._pose, self._est):
            with contextlib.suppress(OSError):
                log.close()
        self.meta["status"] = status
        self.meta["recorded"] = dict(self.counts)
        self.meta.update(extra or {})
        with contextlib.suppress(OSError):
            self.write_meta()


def record_streams(session: Any, keys: dict[str, str], log: McapLog) -> list[Any]:
    """Subscribe ``log`` to the body's keys (``pose``, ``cmd``, ``estimate``: the keys of
    :func:`estimator.live.zenoh_run.keys`); the estimates this session publishes reach it
    too (Zenoh delivers them to the session's own subscribers). Returns the subscribers
    (undeclare them before closing ``log``)."""
    return [_subscribe(session, v, log) for k, v in keys.items()
            if k in ("pose", "cmd", "estimate") or k.startswith("cmd:")]
