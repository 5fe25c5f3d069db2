"""Record pose payloads from Zenoh into run folders, flushed as they arrive.

Layout of ``OUT``::

    OUT/recording.json           key, host start time, t0, status, counters (rewritten at the end)
    OUT/<body>/poses.csv         t,x,y,psi   (run-folder contract; occluded frames left out)
    OUT/<body>/samples.csv       every sample as received (occluded ones too)
    OUT/recording.mcap           with --mcap: every message on the key, as received (below)

poses.csv times are the sample's ``t_src`` when the source has its own timeline
(replay, sim), otherwise ``t - t0`` with ``t0`` the capture time of the first sample
received (or the ``t0`` given). Values are written with 12 significant digits, like
``common.runfolder.write_run``; samples.csv keeps full precision (shortest repr). Both
are ``common.runwriter.CsvLog`` files (flushed per row unless ``flush=False``);
recording.json is replaced atomically. Its ``status`` is ``running`` until :meth:`Recorder.close`
writes ``complete`` (a clean stop: Ctrl-C or the end of ``--duration``) or ``incomplete``
(samples that could not be written, or closed on an error); ``running`` left behind means
the recorder was killed. Readers warn on a recording that is not ``complete``
(:func:`common.runfolder.warn_if_partial`).

Given an :class:`common.mcap.log.McapLog` (``mcap=``), the recorder also logs every
payload of the subscribed key, stats and malformed ones included, on a channel per Zenoh
key, with the receive time (:mod:`common.mcap.log`); the CSV files stay the primary
format. ``tpods mocap record --out X.mcap`` writes only the MCAP file (:func:`subscribe`
with a log and no recorder is :func:`common.mcap.log.subscribe`).
"""

from __future__ import annotations

import math
import threading
import time
from pathlib import Path
from typing import Any

from common.errors import UserError
from common.mcap.log import McapLog
from common.plausible import check_finite_time
from common.runfolder import POSE_COLUMNS
from common.runwriter import CsvLog, run_header, write_json_atomic
from common.wire import decode_pose, sanitize_chunk
from mocap_bridge.sources.replay import SAMPLE_COLUMNS


def _f(v: float | None) -> str:
    return "" if v is None else repr(float(v))


def _bool(v: bool) -> str:
    return "true" if v else "false"


# samples.csv: body, frame, the times and pose values (shortest repr, empty for None),
# occluded, t_rx
_SAMPLE_FORMATS = (str, str, *([_f] * 11), _bool, _f)


class _BodyFiles:
    def __init__(self, folder: Path, flush: bool) -> None:
        folder.mkdir(parents=True, exist_ok=True)
        every = 0.0 if flush else None
        # same %-formatting as write_run (12 significant digits)
        self.poses = CsvLog(folder / "poses.csv", POSE_COLUMNS, "%.12g", flush_every_s=every)
        self.samples = CsvLog(folder / "samples.csv", SAMPLE_COLUMNS, _SAMPLE_FORMATS,
                              flush_every_s=every)
        self.last_t: float | None = None
        self.uses_t_src: bool | None = None
        self.rows = 0

    def close(self) -> None:
        self.poses.close()
        self.samples.close()


class Recorder:
    """Write decoded pose samples per body (thread-safe; call :meth:`handle` per payload).

    Counters: ``received``, ``recorded`` (rows in poses.csv), ``occluded``,
    ``malformed``, ``other_schema`` (e.g. stats messages), ``not_increasing`` (a time
    not after the body's previous one: left out of poses.csv, kept in samples.csv).
    """

    def __init__(self, out: str | Path, key: str = "", t0: float | None = None,
                 flush: bool = True, mcap: McapLog | None = None) -> None:
        check_finite_time(t0, "t0 (--t0)")
        self.out = Path(out)
        try:
            self.out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise UserError(f"{self.out}: cannot create the output folder ({exc.strerror})") from None
        self.key = key
        self.t0 = t0
        self.flush = flush
        self.counters = {"received": 0, "recorded": 0, "occluded": 0, "malformed": 0,
                         "other_schema": 0, "not_increasing": 0}
        self.started = time.time()
        self._files: dict[str, _BodyFiles] = {}
        self._names: dict[str, str] = {}
        self._lock = threading.Lock()
        self._closed = False
        self.last_error = ""
        self.status = "running"
        self.mcap = mcap
        self._write_meta()

    def _write_meta(self) -> None:
        write_json_atomic(self.out / "recording.json", run_header(
            "mocap-recording", created=self.started, key=self.key, t0_host_s=self.t0,
            status=self.status, bodies=dict(self._names), counters=dict(self.counters)))

    def _files_for(self, body: str) -> _BodyFiles:
        bf = self._files.get(body)
        if bf is None:
            name = sanitize_chunk(body)
            while name in self._names.values():  # two raw names, one sanitised name
                name += "_"
            self._names[body] = name
            bf = self._files[body] = _BodyFiles(self.out / name, self.flush)
            self._write_meta()
        return bf

    def handle(self, payload: bytes, t_rx: float | None = None, key: str | None = None
               ) -> dict[str, Any] | None:
        """Decode one payload and write it; returns the sample, or None if skipped.
        ``key``: the Zenoh key it came on (needed to log it to the MCAP file)."""
        if t_rx is None:
            t_rx_ns = time.time_ns()
            t_rx = t_rx_ns / 1e9
        else:
            t_rx_ns = round(t_rx * 1e9)
        if self.mcap is not None and key is not None:
            self.mcap.write(key, payload, t_rx_ns)
        with self._lock:
            if self._closed:
                return None
            self.counters["received"] += 1
            d = decode_pose(payload, self.counters)
            if d is None:
                return None
            bf = self._files_for(d["body"])
            bf.samples.write(d["body"], d["frame"], d["t"], d["t_recv"], d["t_src"],
                             *(d[k] for k in ("x", "y", "z", "qx", "qy", "qz", "qw", "yaw")),
                             d["occluded"], t_rx)
            if self.t0 is None:
                self.t0 = d["t"]
                self._write_meta()
            if d["occluded"]:
                self.counters["occluded"] += 1
            else:
                if bf.uses_t_src is None:
                    bf.uses_t_src = d["t_src"] is not None
                t = d["t_src"] if bf.uses_t_src and d["t_src"] is not None else d["t"] - self.t0
                if not math.isfinite(t):  # never a t = nan row
                    self.counters["malformed"] += 1
                elif bf.last_t is not None and t <= bf.last_t:
                    self.counters["not_increasing"] += 1
                else:
                    bf.poses.write(t, d["x"], d["y"], d["yaw"])
                    bf.last_t = t
                    bf.rows += 1
                    self.counters["recorded"] += 1
            return d

    def close(self, status: str | None = None) -> dict[str, int]:
        """Close the files and write the final status and counters to recording.json.

        ``status`` defaults to ``complete``, or ``incomplete`` when samples could not be
        written (``write_errors``); pass ``incomplete`` when closing on an error. A second
        call does nothing."""
        with self._lock:
            if self._closed:
                return dict(self.counters)
            self._closed = True
            for bf in self._files.values():
                bf.close()
            if status is None:
                status = "incomplete" if self.counters.get("write_errors") else "complete"
            self.status = status
            if self.mcap is not None:
                self.mcap.close(status, {"recorded": self.counters["recorded"]})
            self._write_meta()
            return dict(self.counters)

    @property
    def bodies(self) -> dict[str, str]:
        """Body name to its folder name."""
        return dict(self._names)

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        self.close(None if exc_type is None else "incomplete")


def subscribe(session: Any, key: str, recorder: Recorder):
    """Declare a subscriber on ``key`` feeding ``recorder``; returns it (undeclare when done)."""
    def on_sample(sample: Any) -> None:
        try:
            if recorder.mcap is None:
                recorder.handle(sample.payload.to_bytes())
            else:
                recorder.handle(sample.payload.to_bytes(), key=str(sample.key_expr))
        except OSError as exc:  # disk full, folder removed: count, keep the session alive
            recorder.counters["write_errors"] = recorder.counters.get("write_errors", 0) + 1
            recorder.last_error = f"{exc.strerror or exc}"

    try:
        return session.declare_subscriber(key, on_sample)
    except Exception as exc:
        raise UserError(f"cannot subscribe to {key!r} ({str(exc).splitlines()[0]})") from None
