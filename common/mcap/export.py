"""A run folder as MCAP: the messages the Zenoh streams would have carried (``tpods export mcap``).

One message per row, on the keys the live system uses, with the payloads of
:mod:`common.wire` and the schemas of :mod:`common.wire_schemas`:

| file | key | schema | payload |
|---|---|---|---|
| ``poses.csv`` | ``<mocap prefix>/<body>/pose`` (``tpods/mocap/...``) | ``tpods.pose/1`` | ``frame`` = row number (from 0), ``t = t_recv = t0 + t``, ``t_src = t`` (the row's time, exact), ``x, y``, ``z = 0``, the quaternion of a pure yaw, ``yaw`` = psi wrapped to (-pi, pi] |
| ``commands.csv`` | ``<prefix>/<body>/cmd`` | ``tpods.cmd/1`` | ``seq`` = row number, ``kind`` ``set`` (the last row ``end`` when it closes every valve), ``t = t0 + t``, ``duty`` (4N values for a structure run) |
| ``estimates.csv`` (if present) | ``<prefix>/<body>/estimate`` | ``tpods.estimate/1`` | the columns it holds; ``t_pub``, ``nis``, ``diverged``, ``inconsistent`` are not in the CSV and are left out |
| ``truth.csv`` (if present) | ``<prefix>/<body>/truth`` | ``tpods.truth/1`` | ``t = t0 + t``, ``x, y, psi, u, v, r`` |

``t0`` is the host time of the run's t = 0 where the run says it (``run.json``
``t0_lab`` of a live run), else 0: times stay run times. Messages are written in time
order (at equal times: commands, truth, poses, estimates); ``log_time`` and
``publish_time`` are ``t0 + t`` in ns. So ``tpods replay`` of the file publishes the run
with its timing, and its poses and commands reach ``tpods estimate live --body BODY``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from common.errors import UserError
from common.mcap.log import McapLog, seconds_to_ns
from common.runfolder import Run, read_run, read_table
from common.wire import (
    DEFAULT_PREFIX,
    EST_SCHEMA,
    cmd_key,
    encode_command,
    encode_pose,
    estimate_key,
    pose_key,
    sanitize_chunk,
)
from common.wire_schemas import TRUTH_SCHEMA

MOCAP_PREFIX = "tpods/mocap"
TRUTH_COLUMNS = ("t", "x", "y", "psi", "u", "v", "r")
_STATE = ("x", "y", "psi", "u", "v", "r")
_EST_NUMBERS = ("mass_kg", "mass_sigma_kg", "izz_kgm2", "izz_sigma_kgm2", "mass_sigma_noise_kg",
                "mass_sigma_thrust_kg", "izz_sigma_noise_kgm2", "izz_sigma_thrust_kgm2")


def truth_key(body: str, prefix: str = DEFAULT_PREFIX) -> str:
    """``<prefix>/<body>/truth``: a simulated run's true state in an exported file."""
    return f"{prefix.strip('/')}/{sanitize_chunk(body)}/truth"


def _wrap(a: float) -> float:
    """``a`` in (-pi, pi]; unchanged (bit for bit) when it already is."""
    if -math.pi < a <= math.pi:
        return a
    w = math.remainder(a, 2 * math.pi)
    return math.pi if w <= -math.pi else w


def _num(v: Any) -> float | None:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


def _read_estimates(path: Path) -> list[dict[str, Any]]:
    import pandas as pd  # lazy: only runs with estimates.csv need it

    try:
        df = pd.read_csv(path, keep_default_na=True)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise UserError(f"{path}: not a readable estimates file ({str(exc).splitlines()[0]})") from None
    if "t" not in df.columns:
        raise UserError(f"{path}: missing column t")
    return df.to_dict("records")


def body_of(run: Run) -> str:
    """The run's body: run.json ``body``, else the folder name (as ``tpods mocap bridge
    --source replay:RUN_DIR`` names it)."""
    b = run.meta.get("body")
    return b if isinstance(b, str) and b.strip() else run.path.resolve().name


def run_messages(run_dir: str | Path, *, body: str | None = None, prefix: str = DEFAULT_PREFIX,
                 mocap_prefix: str = MOCAP_PREFIX, t0: float | None = None
                 ) -> tuple[list[tuple[float, int, str, bytes]], dict[str, Any]]:
    """The messages of a run folder as ``(time s, order, key, payload)`` sorted by time,
    and a description (body, t0, counts per file)."""
    run = read_run(run_dir)
    path = run.path
    body = body or body_of(run)
    if t0 is None:
        t0 = _num(run.meta.get("t0_lab")) or 0.0
    msgs: list[tuple[float, int, str, bytes]] = []
    counts: dict[str, int] = {}

    if run.duty_pct is not None:
        k = cmd_key(body, prefix)
        n = len(run.cmd_t)
        for i, (t, duty) in enumerate(zip(run.cmd_t, run.duty_pct, strict=True)):
            kind = "end" if i == n - 1 and not np.any(duty) else "set"
            msgs.append((t0 + t, 0, k, encode_command(body, i, t0 + float(t), duty, kind)))
        counts["commands.csv"] = n

    truth_file = path / "truth.csv"
    if truth_file.is_file():
        k = truth_key(body, prefix)
        tv = read_table(truth_file, TRUTH_COLUMNS)
        for row in tv:
            d = {"schema": TRUTH_SCHEMA, "body": body, "t": t0 + float(row[0]),
                 **{c: float(v) for c, v in zip(TRUTH_COLUMNS[1:], row[1:], strict=True)}}
            msgs.append((t0 + row[0], 1, k, json.dumps(d, separators=(",", ":")).encode()))
        counts["truth.csv"] = len(tv)

    k = pose_key(mocap_prefix, body)
    for i, (t, (x, y, psi)) in enumerate(zip(run.pose_t, run.pose, strict=True)):
        yaw = _wrap(float(psi))
        pose = (float(x), float(y), 0.0, 0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2), yaw)
        ts = t0 + float(t)
        msgs.append((ts, 2, k, encode_pose(body, i, ts, ts, pose, t_src=float(t))))
    counts["poses.csv"] = len(run.pose_t)

    est_file = path / "estimates.csv"
    if est_file.is_file():
        k = estimate_key(body, prefix)
        rows = _read_estimates(est_file)
        method = run.meta.get("method")
        for i, r in enumerate(rows):
            t = _num(r.get("t"))
            if t is None:
                raise UserError(f"{est_file}: row {i + 2}: t is not a number")
            d: dict[str, Any] = {"schema": EST_SCHEMA, "body": body, "seq": i, "t": t0 + t}
            if _num(r.get("frame")) is not None:
                d["frame"] = int(r["frame"])
            if isinstance(method, str):
                d["method"] = method
            d["phase"] = str(r.get("phase", ""))
            for c in _EST_NUMBERS:
                if c in r:
                    d[c] = _num(r[c])
            if all(s in r for s in _STATE):
                d["state"] = {s: _num(r[s]) for s in _STATE}
            if all(f"sigma_{s}" in r for s in _STATE):
                d["state_sigma"] = {s: _num(r[f"sigma_{s}"]) for s in _STATE}
            msgs.append((t0 + t, 3, k, json.dumps(d, separators=(",", ":")).encode()))
        counts["estimates.csv"] = len(rows)

    msgs.sort(key=lambda m: (m[0], m[1]))
    return msgs, {"body": body, "t0": t0, "counts": counts, "run": str(path)}


def export_run(run_dir: str | Path, out: str | Path, **kwargs: Any) -> dict[str, Any]:
    """Write the run folder ``run_dir`` as the MCAP file ``out`` (see the module doc);
    returns the description of :func:`run_messages` with the message count."""
    msgs, info = run_messages(run_dir, **kwargs)
    log = McapLog(out, flush_every_s=0, chunk_size=1024 * 1024,
                  meta={"command": "tpods export mcap", "run": info["run"], "body": info["body"],
                        "t0_s": info["t0"]})
    try:
        for t, _order, key, payload in msgs:
            ns = seconds_to_ns(t)
            if ns is None:
                raise UserError(f"{run_dir}: time {t:g} s is before the Unix epoch; give --t0")
            log.write(key, payload, ns, ns)
    except BaseException:
        log.close("incomplete")
        raise
    log.close("complete")
    info["messages"] = len(msgs)
    return info


def export_run_file(run_dir: str | Path, out: str | Path, *, force: bool = False,
                    prefix: str = DEFAULT_PREFIX, mocap_prefix: str = MOCAP_PREFIX,
                    **kwargs: Any) -> dict[str, Any]:
    """The use case behind ``tpods export mcap``: the run folder ``run_dir`` as the MCAP file
    ``out`` (a name ending in .mcap; an existing one replaced only with ``force``), written
    beside and renamed; ``kwargs`` as for :func:`run_messages` (``body``, ``t0``). Returns
    the description of :func:`export_run` with the file's ``path``."""
    from common.outputs import ResultFile, is_mcap

    if not is_mcap(out):
        raise UserError(f"--out {out}: tpods export mcap writes one MCAP file; give a name "
                        "ending in .mcap")
    for opt, v in (("--prefix", prefix), ("--mocap-prefix", mocap_prefix)):
        if not v.strip("/"):  # a key cannot start with '/'
            raise UserError(f"{opt} must not be empty")
    if not Path(run_dir).is_dir():
        raise UserError(f"{run_dir}: run folder not found")
    dest = ResultFile(out, force=force)
    with dest.writing() as tmp:
        info = export_run(run_dir, tmp, prefix=prefix, mocap_prefix=mocap_prefix, **kwargs)
    return {**info, "path": dest.path}

