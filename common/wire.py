"""Wire formats of the Zenoh streams: keys, pose and command payloads (pure, no I/O).

Every stream is JSON with Zenoh encoding ``application/json`` and a ``schema`` field;
a reader refuses other schemas. The bridge, the recorder, the valve player and the live
estimator all encode and decode through this module, so a format lives in one place.

Pose, key ``<prefix>/<body>/pose`` (prefix ``tpods/mocap``), schema ``tpods.pose/1``::

    {"schema": "tpods.pose/1", "body": "tpods1", "frame": 1234,
     "t": 1763770000.123,      # capture time, s, host clock (time.time()): t_recv - latency
     "t_recv": 1763770000.125, # host time the bridge received the frame, s
     "x": 0.1, "y": -0.2, "z": 0.01,          # metres, table frame (z along the normal)
     "qx": 0, "qy": 0, "qz": 0.38, "qw": 0.92, # orientation, table frame, unit quaternion
     "yaw": 0.78,              # rad, about the table normal, wrapped to (-pi, pi]
     "occluded": false,
     "t_src": 12.5}            # optional: time on the source's own timeline (replay, sim), s

An occluded body has ``"occluded": true`` and ``null`` for x, y, z, qx, qy, qz, qw, yaw
(never fake zeros).

Estimate, key ``<prefix>/<body>/estimate`` (prefix ``tpods``), schema ``tpods.estimate/1``:
documented with the live estimator (:mod:`estimator.live.runtime`), which fills
:data:`EST_FMT` on its hot path.

Command, key ``<prefix>/<body>/cmd`` (prefix ``tpods``), schema ``tpods.cmd/1``::

    {"schema": "tpods.cmd/1", "body": "tpods1", "seq": 12, "kind": "set",  # or hold, end
     "t": 3.2,                 # lab time the duties take effect, s
     "duty": [50.0, 50.0, 0.0, 0.0]}  # percent, one per valve channel
"""

from __future__ import annotations

import json
import math
import re
from functools import lru_cache
from typing import Any

SCHEMA = "tpods.pose/1"
STATS_SCHEMA = "tpods.mocap-stats/1"
ENCODING = "application/json"
POSE_FIELDS = ("x", "y", "z", "qx", "qy", "qz", "qw", "yaw")


# ------------------------------------------------------------------ keys

_KEY_BAD = re.compile(r"[^A-Za-z0-9_.\-]")


def sanitize_chunk(name: str) -> str:
    """A body name as one valid Zenoh key chunk (and file name): ``[A-Za-z0-9_.-]+``."""
    s = _KEY_BAD.sub("_", name.strip())
    if not s or set(s) <= {"."}:
        s = "_" + s
    return s


def pose_key(prefix: str, body: str) -> str:
    """``<prefix>/<body>/pose`` with the body name sanitised."""
    return f"{prefix.rstrip('/')}/{sanitize_chunk(body)}/pose"


# ------------------------------------------------------------------ payload


_HEAD = '{"schema":"' + SCHEMA + '","body":%s,"frame":%d,"t":%r,"t_recv":%r,'
_FMT_POSE = _HEAD + ('"x":%.17g,"y":%.17g,"z":%.17g,"qx":%.17g,"qy":%.17g,"qz":%.17g,"qw":%.17g,'
                     '"yaw":%.17g,"occluded":false')
_FMT_OCC = _HEAD + ('"x":null,"y":null,"z":null,"qx":null,"qy":null,"qz":null,"qw":null,'
                    '"yaw":null,"occluded":true')


@lru_cache(maxsize=4096)
def _json_str(s: str) -> str:
    return json.dumps(s)


def encode_pose(body: str, frame: int, t: float, t_recv: float,
                pose: tuple[float, ...] | None, t_src: float | None = None) -> bytes:
    """Encode one pose payload (schema ``tpods.pose/1``).

    Every value keeps full double precision (17 significant digits), so a decoded
    payload holds exactly the floats that were encoded.

    Args:
        pose: table-frame ``(x, y, z, qx, qy, qz, qw, yaw)`` (m, unit quaternion, rad),
            or None when the body is occluded. Any non-finite value makes it occluded.
    """
    head = (_json_str(body), frame, float(t), float(t_recv))
    if pose is not None and math.isfinite(sum(pose)):
        text = _FMT_POSE % (head + tuple(pose))
    else:
        text = _FMT_OCC % head
    if t_src is not None:
        text += ',"t_src":%r' % float(t_src)  # noqa: UP031 (one format family, fast path)
    return (text + "}").encode()


def _is_num(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def decode_pose(payload: bytes | bytearray | memoryview | str,
                counters: dict[str, int] | None = None) -> dict[str, Any] | None:
    """Decode and validate a pose payload; None for anything malformed.

    When ``counters`` is given, ``counters['malformed']`` is incremented for a bad
    payload and ``counters['other_schema']`` for valid JSON of another schema (e.g.
    the stats messages on ``tpods/mocap/stats``), which also return None.
    """
    def bad(kind: str = "malformed") -> None:
        if counters is not None:
            counters[kind] = counters.get(kind, 0) + 1
        return None

    try:
        d = json.loads(bytes(payload) if not isinstance(payload, str) else payload)
    except (ValueError, UnicodeDecodeError):
        return bad()
    if not isinstance(d, dict):
        return bad()
    schema = d.get("schema")
    if schema != SCHEMA:
        return bad("other_schema" if isinstance(schema, str) and not schema.startswith("tpods.pose/")
                   else "malformed")
    occ = d.get("occluded")
    frame = d.get("frame")
    if (not isinstance(d.get("body"), str) or not isinstance(occ, bool)
            or not isinstance(frame, int) or isinstance(frame, bool)
            or not _is_num(d.get("t")) or not _is_num(d.get("t_recv"))):
        return bad()
    if d.get("t_src") is not None and not _is_num(d["t_src"]):
        return bad()
    if occ:
        for k in POSE_FIELDS:
            d[k] = None
    else:
        if not all(_is_num(d.get(k)) for k in POSE_FIELDS):
            return bad()
        if not -math.pi - 1e-9 <= d["yaw"] <= math.pi + 1e-9:
            return bad()
        for k in POSE_FIELDS:
            d[k] = float(d[k])
    d["t"] = float(d["t"])
    d["t_recv"] = float(d["t_recv"])
    d.setdefault("t_src", None)
    return d


# ------------------------------------------------------------------ commands

CMD_SCHEMA = "tpods.cmd/1"
CMD_KINDS = ("set", "hold", "end")
DEFAULT_PREFIX = "tpods"


def cmd_key(body: str, prefix: str = DEFAULT_PREFIX) -> str:
    """``<prefix>/<body>/cmd`` with the body name sanitised into one key chunk."""
    return f"{prefix.strip('/')}/{sanitize_chunk(body)}/cmd"


def encode_command(body: str, seq: int, t: float, duty_pct, kind: str = "set") -> bytes:
    """One command payload (schema ``tpods.cmd/1``); duties in percent, ``t`` lab seconds."""
    d = ",".join(repr(float(x)) for x in duty_pct)
    return ('{"schema":"%s","body":%s,"seq":%d,"kind":"%s","t":%r,"duty":[%s]}'  # noqa: UP031
            % (CMD_SCHEMA, json.dumps(body), int(seq), kind, float(t), d)).encode()


def decode_command(payload: bytes | bytearray | memoryview | str,
                   counters: dict[str, int] | None = None, n_channels: int = 4
                   ) -> dict[str, Any] | None:
    """Decode and validate a command payload; None (and ``counters['malformed']`` + 1) if bad."""
    def bad() -> None:
        if counters is not None:
            counters["malformed"] = counters.get("malformed", 0) + 1
        return None

    try:
        d = json.loads(bytes(payload) if not isinstance(payload, str) else payload)
    except (ValueError, UnicodeDecodeError):
        return bad()
    if not isinstance(d, dict) or d.get("schema") != CMD_SCHEMA:
        return bad()
    t, duty, seq, kind = d.get("t"), d.get("duty"), d.get("seq"), d.get("kind", "set")
    if (not isinstance(t, (int, float)) or isinstance(t, bool) or not math.isfinite(t)
            or not isinstance(seq, int) or isinstance(seq, bool) or kind not in CMD_KINDS
            or not isinstance(duty, list) or len(duty) != n_channels):
        return bad()
    try:
        vals = [float(x) for x in duty]
    except (TypeError, ValueError):
        return bad()
    if any(isinstance(x, bool) for x in duty) or not all(math.isfinite(x) and 0.0 <= x <= 100.0
                                                        for x in vals):
        return bad()
    d["t"] = float(t)
    d["duty"] = vals
    return d


# ------------------------------------------------------------------ estimates

EST_SCHEMA = "tpods.estimate/1"


def estimate_key(body: str, prefix: str = DEFAULT_PREFIX) -> str:
    """``<prefix>/<body>/estimate`` with the body name sanitised into one key chunk."""
    return f"{prefix.strip('/')}/{sanitize_chunk(body)}/estimate"


EST_FMT = ('{"schema":"' + EST_SCHEMA + '","body":%s,"seq":%d,"t":%r,"frame":%d,"t_pub":%r,'
            '"method":"%s","phase":"%s","mass_kg":%r,"mass_sigma_kg":%r,"izz_kgm2":%r,'
            '"izz_sigma_kgm2":%r,"mass_sigma_noise_kg":%r,"mass_sigma_thrust_kg":%r,'
            '"izz_sigma_noise_kgm2":%r,"izz_sigma_thrust_kgm2":%r,'
            '"state":{"x":%r,"y":%r,"psi":%r,"u":%r,"v":%r,"r":%r},'
            '"state_sigma":{"x":%r,"y":%r,"psi":%r,"u":%r,"v":%r,"r":%r},"n_updates":%d,'
            '"nis":%s,"diverged":%s,"inconsistent":%s,"rev":%d,"revised":%s}')
"""The estimate payload of a module (``%`` fields in this order). ``rev`` and ``revised``
come last and are optional for readers: a payload without them is a first estimate."""


def encode_estimate(d: dict[str, Any]) -> bytes:
    return json.dumps(d, separators=(",", ":")).encode()


def decode_estimate(payload: bytes | bytearray | memoryview | str) -> dict[str, Any] | None:
    """Decode an estimate payload; None if it is not one."""
    try:
        d = json.loads(bytes(payload) if not isinstance(payload, str) else payload)
    except (ValueError, UnicodeDecodeError):
        return None
    if not isinstance(d, dict) or d.get("schema") != EST_SCHEMA:
        return None
    d.setdefault("rev", 0)  # written before estimates were revised: a first estimate
    d.setdefault("revised", bool(d["rev"]))
    return d
