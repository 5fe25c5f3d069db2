"""JSON Schemas of the Zenoh payloads (:mod:`common.wire`), written once for MCAP files.

An MCAP channel of JSON messages names its schema (schema encoding ``jsonschema``): the
recorders, ``tpods export mcap`` and viewers (Foxglove reads them to list the fields) all
take them from here. They describe what :mod:`common.wire` encodes; the decoders in
:mod:`common.wire` remain the validators the toolkit uses.

``tpods.truth/1`` is not a Zenoh stream: it carries a simulated run's ``truth.csv`` rows
in an exported MCAP file (``tpods/<body>/truth``).
"""

from __future__ import annotations

import json
from typing import Any

from common.wire import CMD_KINDS, CMD_SCHEMA, EST_SCHEMA, SCHEMA, STATS_SCHEMA

TRUTH_SCHEMA = "tpods.truth/1"

_NUM = {"type": "number"}
_NUM_OR_NULL = {"type": ["number", "null"]}
_DRAFT = "https://json-schema.org/draft/2020-12/schema"


def _payload(title: str, description: str, properties: dict[str, Any],
             required: list[str], per_body: bool = True) -> dict[str, Any]:
    """The JSON Schema of one payload: an object whose ``schema`` field is ``title`` and,
    ``per_body``, whose ``body`` field names the body (both required)."""
    head = ["schema", "body"] if per_body else ["schema"]
    return {"$schema": _DRAFT, "title": title, "type": "object", "description": description,
            "properties": {"schema": {"const": title, "description": "payload schema name"},
                           **({"body": {"type": "string"}} if per_body else {}), **properties},
            "required": [*head, *required]}


POSE = _payload(
    SCHEMA,
    "A rigid body's pose from the mocap bridge (key <prefix>/<body>/pose). "
    "Occluded: occluded true and null pose values.",
    {"frame": {"type": "integer", "description": "mocap frame number"},
     "t": {**_NUM, "description": "capture time, s, host clock (time.time())"},
     "t_recv": {**_NUM, "description": "host time the bridge received the frame, s"},
     **{k: {**_NUM_OR_NULL, "description": "m, table frame"} for k in ("x", "y", "z")},
     **{k: {**_NUM_OR_NULL, "description": "unit quaternion, table frame"}
        for k in ("qx", "qy", "qz", "qw")},
     "yaw": {**_NUM_OR_NULL, "description": "rad about the table normal, (-pi, pi]"},
     "occluded": {"type": "boolean"},
     "t_src": {**_NUM_OR_NULL, "description": "time on the source's own timeline (replay, sim), s"}},
    ["frame", "t", "t_recv", "x", "y", "z", "qx", "qy", "qz", "qw", "yaw", "occluded"])

CMD = _payload(
    CMD_SCHEMA,
    "A valve command of the player (key <prefix>/<body>/cmd): duties in force "
    "from t (zero-order hold).",
    {"seq": {"type": "integer", "description": "counts every message of the player"},
     "kind": {"enum": list(CMD_KINDS)},
     "t": {**_NUM, "description": "lab time the duties take effect, s"},
     "duty": {"type": "array", "items": {"type": "number", "minimum": 0, "maximum": 100},
              "description": "percent per valve channel (0 = closed)"}},
    ["seq", "kind", "t", "duty"])

_STATE = {"type": "object", "properties": {k: _NUM_OR_NULL for k in ("x", "y", "psi", "u", "v", "r")},
          "description": "x, y (m), psi (rad), u, v (m/s), r (rad/s)"}

ESTIMATE = _payload(
    EST_SCHEMA,
    "A live estimate (key <prefix>/<body>/estimate). An exported run folder's "
    "estimates.csv leaves out what the CSV does not hold (t_pub, method, nis, "
    "diverged, inconsistent).",
    {"seq": {"type": "integer"},
     "t": {**_NUM, "description": "capture time of the last pose used, s"},
     "frame": {"type": "integer"},
     "t_pub": {**_NUM, "description": "host time of publishing, s"},
     "method": {"type": "string"},
     "phase": {"type": "string"},
     "mass_kg": _NUM_OR_NULL, "mass_sigma_kg": _NUM_OR_NULL,
     "izz_kgm2": _NUM_OR_NULL, "izz_sigma_kgm2": _NUM_OR_NULL,
     "mass_sigma_noise_kg": _NUM_OR_NULL, "mass_sigma_thrust_kg": _NUM_OR_NULL,
     "izz_sigma_noise_kgm2": _NUM_OR_NULL, "izz_sigma_thrust_kgm2": _NUM_OR_NULL,
     "state": _STATE, "state_sigma": _STATE,
     "n_updates": {"type": "integer"},
     "nis": _NUM_OR_NULL,
     "diverged": {"type": "boolean"},
     "inconsistent": {"type": "boolean"},
     "rev": {"type": "integer", "minimum": 0,
             "description": "revision of the estimate for this pose: 0 the first, n after the "
                            "filter re-ran the pose n times for commands that arrived after it "
                            "(absent: 0)"},
     "revised": {"type": "boolean",
                 "description": "rev > 0: this estimate replaces one published for the same "
                                "pose (t, frame)"}},
    ["t", "phase", "mass_kg", "mass_sigma_kg", "izz_kgm2", "izz_sigma_kgm2"])

STATS = _payload(
    STATS_SCHEMA,
    "The bridge's statistics (key tpods/mocap/stats, every second); fields in docs/mocap.md.",
    {"t": _NUM},
    [], per_body=False)

TRUTH = _payload(
    TRUTH_SCHEMA,
    "A simulated run's true state at a pose time (truth.csv; key <prefix>/<body>/truth).",
    {"t": {**_NUM, "description": "run time, s"},
     **{k: _NUM for k in ("x", "y", "psi", "u", "v", "r")}},
    ["t", "x", "y", "psi", "u", "v", "r"])

SCHEMAS: dict[str, dict[str, Any]] = {s["title"]: s for s in (POSE, CMD, ESTIMATE, STATS, TRUTH)}
"""Schema name (the payload's ``schema`` field) to its JSON Schema."""


def schema_bytes(name: str) -> bytes:
    """The JSON Schema of ``name`` as MCAP schema data (compact UTF-8 JSON)."""
    return json.dumps(SCHEMAS[name], separators=(",", ":")).encode()
