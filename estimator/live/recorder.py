"""The live estimator's run folder: what it saw, written as it goes."""

from __future__ import annotations

import contextlib
import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from common.errors import UserError
from estimator.filters.ekf import STATE_NAMES


class LiveRecorder:
    """What the live estimator saw, as a run folder written as it goes.

    - ``commands.csv``: every command received (``set``, ``hold``, ``end``; also those too
      late for the live filter) in arrival order, times from ``t0`` (the first command's
      lab time); flushed per row.
    - ``poses.csv``: the aligned poses the filter used, written as soon as a command
      row at or after them exists (so the folder is always a valid run: a kill loses
      at most the poses after the last command or hold message, 0.1 s by default).
    - ``estimates.csv``: the filter's mean and sigma after every update.
    - ``run.json``: settings, ``t0_lab``, status (``running`` until the end: left
      behind, it means the process died), counters and the final estimate.
    """

    def __init__(self, out: str | Path, meta: dict[str, Any], n_channels: int = 4,
                 flush_every_s: float = 0.1) -> None:
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
        self.n_channels = n_channels
        self._cmd = (self.out / "commands.csv").open("w", buffering=1)
        self._cmd.write("t," + ",".join(f"d{i + 1}" for i in range(n_channels)) + "\n")
        self._pose = (self.out / "poses.csv").open("w", buffering=1)
        self._pose.write("t,x,y,psi\n")
        self._est = (self.out / "estimates.csv").open("w")
        self._est.write("t,frame,phase,mass_kg,mass_sigma_kg,izz_kgm2,izz_sigma_kgm2,"
                        + ",".join(STATE_NAMES[:6]) + ","
                        + ",".join(f"sigma_{n}" for n in STATE_NAMES[:6]) + "\n")
        for fh in (self._cmd, self._pose, self._est):
            fh.flush()
        self.last_cmd_t = -math.inf
        self.last_duty: tuple[float, ...] | None = None
        self.last_pose_t = -math.inf
        self._pending: list[tuple[float, float, float, float]] = []
        self.counts = {"commands": 0, "commands_unrecorded": 0, "poses": 0, "estimates": 0}
        self._flush_every = flush_every_s
        self._last_flush = time.monotonic()
        self.closed = False
        self.write_meta()

    def write_meta(self) -> None:
        self.meta["t0_lab"] = self.t0
        tmp = self.out / "run.json.tmp"
        tmp.write_text(json.dumps(self.meta, indent=2, default=_json_default) + "\n")
        tmp.replace(self.out / "run.json")

    def command(self, t: float, duty) -> None:
        if self.t0 is None:
            self.t0 = t
            self.write_meta()
        if not t > self.last_cmd_t:
            self.counts["commands_unrecorded"] += 1
            return
        self._cmd.write("%.9f," % (t - self.t0) + ",".join("%.6g" % x for x in duty) + "\n")  # noqa: UP031
        self._cmd.flush()
        self.last_cmd_t = t
        self.last_duty = tuple(duty)
        self.counts["commands"] += 1
        self._write_covered()

    def pose(self, t: float, x: float, y: float, yaw: float) -> None:
        self._pending.append((t, x, y, yaw))
        self._write_covered()

    def _write_covered(self) -> None:
        if not self._pending or self.t0 is None:
            return
        n = 0
        for p in self._pending:
            if p[0] > self.last_cmd_t:
                break
            if p[0] > self.last_pose_t and p[0] >= self.t0:
                self._pose.write("%.9f,%.12g,%.12g,%.12g\n" % (p[0] - self.t0, p[1], p[2], p[3]))  # noqa: UP031
                self.last_pose_t = p[0]
                self.counts["poses"] += 1
            n += 1
        if n:
            del self._pending[:n]
            self._pose.flush()

    def estimate(self, t: float, frame: int, phase: str, z: np.ndarray, sig: np.ndarray) -> None:
        t0 = self.t0 if self.t0 is not None else t
        self._est.write("%.9f,%d,%s," % (t - t0, frame, phase)  # noqa: UP031
                        + "%.10g,%.6g,%.10g,%.6g," % (z[6], sig[6], z[7], sig[7])  # noqa: UP031
                        + ",".join("%.10g" % v for v in z[:6]) + ","  # noqa: UP031
                        + ",".join("%.6g" % v for v in sig[:6]) + "\n")  # noqa: UP031
        self.counts["estimates"] += 1
        now = time.monotonic()
        if now - self._last_flush >= self._flush_every:
            self._est.flush()
            self._last_flush = now

    def close(self, status: str, extra: dict[str, Any] | None = None) -> None:
        """Close the files: a last hold row covers the poses still pending."""
        if self.closed:
            return
        self.closed = True
        if self._pending and self.last_duty is not None:
            t_last = self._pending[-1][0]
            if t_last > self.last_cmd_t:
                self.command(t_last, self.last_duty)
        for fh in (self._cmd, self._pose, self._est):
            with contextlib.suppress(OSError):
                fh.close()
        self.meta["status"] = status
        self.meta["recorded"] = dict(self.counts)
        self.meta.update(extra or {})
        with contextlib.suppress(OSError):
            self.write_meta()


def _json_default(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)

