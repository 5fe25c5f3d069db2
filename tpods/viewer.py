"""Serve the live Zenoh streams to Foxglove (``tpods view``).

The viewer subscribes to the poses (``<mocap-prefix>/<body>/pose``), the valve commands
(``<prefix>/<body>/cmd``) and the live estimates (``<prefix>/<body>/estimate``), decodes
them with :mod:`common.wire` and logs them on the channels of a Foxglove WebSocket server
(the Foxglove SDK, protocol ``foxglove.websocket.v1``). Per body ``<b>``:

=========================  ============================  =====================================
topic                      schema (encoding)             what
=========================  ============================  =====================================
``/tpods/<b>/frame``       ``foxglove.FrameTransform``   the body frame in the ``table`` frame:
                           (protobuf)                    x, y, z and the yaw as a quaternion
``/tpods/<b>/pose``        ``tpods.view.pose/1`` (json)  t, frame, x, y, z, yaw, yaw_deg,
                                                         occluded (null pose when occluded)
``/tpods/<b>/duty``        ``tpods.view.duty/1`` (json)  t, seq, kind, duty[4], d1..d4 (%)
``/tpods/<b>/estimate``    ``tpods.view.estimate/1``     mass and Izz with their 1-sigma band
                           (json)                        (value -/+ total sigma) and the noise
                                                         and thrust parts of sigma
``/tpods/<b>/health``      ``tpods.view.health/1``       n_updates, nis, diverged,
                           (json)                        inconsistent, phase, status, lag_s
=========================  ============================  =====================================

and for the run: ``/tpods/clock`` (``tpods.view.clock/1``: lab time of the last pose, its
body and frame, host time of arrival and the difference) and ``/tpods/view/stats``
(``tpods.view.stats/1``: the viewer's counters, every second). The server also broadcasts
the lab time of the last pose as its time (capability ``time``), so the viewer's clock is
the run's.

Each message is logged with its own lab time (pose and command ``t``, estimate ``t``: the
capture time of the last pose used) as log time, so every plot shares the run's timeline.
Bad payloads are counted (``counters``) and skipped. Channels of a body are created when
it is first seen (or at start for the bodies given); the server advertises them then.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Iterable
from typing import Any

import foxglove
from foxglove.channels import FrameTransformChannel
from foxglove.messages import FrameTransform, Quaternion, Timestamp, Vector3

from common.errors import UserError
from common.wire import (
    DEFAULT_PREFIX,
    cmd_key,
    decode_command,
    decode_estimate,
    decode_pose,
    estimate_key,
    pose_key,
    sanitize_chunk,
)

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8765
DEFAULT_MOCAP_PREFIX = "tpods/mocap"
DEFAULT_POSE_RATE = 50.0
"""Poses forwarded per body and second (a browser does not need the mocap's 100-2000 Hz)."""
TABLE_FRAME = "table"
N_CHANNELS = 4
STATS_PERIOD_S = 1.0
CLOCK_RESET_S = 1.0
"""A pose older than the body's last shown one by more than this starts a new run (a
restarted clock); a less old one is out of order and skipped."""

_NUM = {"type": "number"}
_NUM_OR_NULL = {"type": ["number", "null"]}
_DRAFT = "https://json-schema.org/draft/2020-12/schema"


def _schema(title: str, description: str, props: dict[str, Any]) -> dict[str, Any]:
    return {"$schema": _DRAFT, "title": title, "type": "object", "description": description,
            "properties": props, "required": list(props)}


POSE_VIEW = _schema("tpods.view.pose/1", "A body's pose (table frame); null when occluded.", {
    "body": {"type": "string"}, "t": {**_NUM, "description": "capture time, lab clock, s"},
    "frame": {"type": "integer"},
    **{k: {**_NUM_OR_NULL, "description": "m"} for k in ("x", "y", "z")},
    "yaw": {**_NUM_OR_NULL, "description": "rad"}, "yaw_deg": {**_NUM_OR_NULL, "description": "deg"},
    "occluded": {"type": "boolean"}})
DUTY_VIEW = _schema("tpods.view.duty/1", "The valve duties in force from t (zero-order hold).", {
    "body": {"type": "string"}, "t": {**_NUM, "description": "lab time, s"},
    "seq": {"type": "integer"}, "kind": {"enum": ["set", "hold", "end"]},
    "duty": {"type": "array", "items": _NUM, "description": "percent per channel"},
    **{f"d{i}": {**_NUM, "description": f"channel {i}, percent"} for i in range(1, N_CHANNELS + 1)}})
_EST_PROPS: dict[str, Any] = {
    "body": {"type": "string"},
    "t": {**_NUM, "description": "capture time of the last pose used, s"},
    "t_pub": _NUM_OR_NULL, "method": {"type": ["string", "null"]},
    "phase": {"type": ["string", "null"]}}
for _name, _unit in (("mass", "kg"), ("izz", "kgm2")):
    for _suffix, _what in (("", "estimate"), ("_sigma", "total 1-sigma"),
                           ("_lo", "estimate - total sigma"), ("_hi", "estimate + total sigma"),
                           ("_sigma_noise", "sigma: measurement noise"),
                           ("_sigma_thrust", "sigma: thrust table")):
        _EST_PROPS[f"{_name}{_suffix}_{_unit}"] = {**_NUM_OR_NULL, "description": _what}
ESTIMATE_VIEW = _schema("tpods.view.estimate/1",
                        "A live estimate with its 1-sigma band (total = noise and thrust parts "
                        "combined by root-sum-square).", _EST_PROPS)
HEALTH_VIEW = _schema("tpods.view.health/1", "The live estimator's health.", {
    "body": {"type": "string"}, "t": _NUM,
    "n_updates": {"type": ["integer", "null"]}, "nis": _NUM_OR_NULL,
    "diverged": {"type": "boolean"}, "inconsistent": {"type": "boolean"},
    "phase": {"type": ["string", "null"]}, "method": {"type": ["string", "null"]},
    "status": {"enum": ["ok", "inconsistent", "diverged"]},
    "status_level": {"type": "integer", "description": "0 ok, 1 inconsistent, 2 diverged"},
    "lag_s": {**_NUM_OR_NULL, "description": "t_pub - t: how far the estimate trails its "
                                            "last pose (the estimator's backlog), s"}})
CLOCK_VIEW = _schema("tpods.view.clock/1", "The run's clock: lab time of the last pose.", {
    "t_lab": {**_NUM, "description": "capture time of the newest pose, s"},
    "body": {"type": "string"}, "frame": {"type": "integer"},
    "t_host": {**_NUM, "description": "host time the viewer received it, s"},
    "lag_s": {**_NUM, "description": "t_host - t_lab, s"}})
STATS_VIEW = {"$schema": _DRAFT, "title": "tpods.view.stats/1", "type": "object",
              "description": "The viewer's counters (received, skipped and why).",
              "properties": {"t_host": _NUM, "bodies": {"type": "array", "items": {"type": "string"}},
                             "counters": {"type": "object", "additionalProperties": {"type": "integer"}}},
              "required": ["t_host", "bodies", "counters"]}


def topics_for(body: str) -> dict[str, str]:
    """The Foxglove topics of one body, by kind (``frame``, ``pose``, ``duty``, ``estimate``,
    ``health``)."""
    b = sanitize_chunk(body)
    return {k: f"/tpods/{b}/{k}" for k in ("frame", "pose", "duty", "estimate", "health")}


CLOCK_TOPIC = "/tpods/clock"
STATS_TOPIC = "/tpods/view/stats"


def yaw_quaternion(yaw: float) -> tuple[float, float, float, float]:
    """``(x, y, z, w)`` of a rotation by ``yaw`` about the table normal."""
    return 0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0)


def _ns(t: float) -> int:
    return max(0, int(round(t * 1e9)))


def _num(v: Any) -> float | None:
    """A finite number as float, else None (null in the message)."""
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        return None
    return float(v)


def _band(d: dict[str, Any], name: str, unit: str) -> dict[str, float | None]:
    v = _num(d.get(f"{name}_{unit}"))
    s = _num(d.get(f"{name}_sigma_{unit}"))
    return {f"{name}_{unit}": v, f"{name}_sigma_{unit}": s,
            f"{name}_lo_{unit}": None if v is None or s is None else v - s,
            f"{name}_hi_{unit}": None if v is None or s is None else v + s,
            f"{name}_sigma_noise_{unit}": _num(d.get(f"{name}_sigma_noise_{unit}")),
            f"{name}_sigma_thrust_{unit}": _num(d.get(f"{name}_sigma_thrust_{unit}"))}


def estimate_view(body: str, d: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]] | None:
    """The estimate and health messages of a decoded ``tpods.estimate/1``; None if it lacks
    a finite ``t`` or carries fields of the wrong type."""
    t = _num(d.get("t"))
    if t is None:
        return None
    method, phase, n = d.get("method"), d.get("phase"), d.get("n_updates")
    if (method is not None and not isinstance(method, str)) or \
            (phase is not None and not isinstance(phase, str)) or \
            (n is not None and (isinstance(n, bool) or not isinstance(n, int))):
        return None
    for k in ("mass_kg", "mass_sigma_kg", "izz_kgm2", "izz_sigma_kgm2", "nis", "t_pub"):
        v = d.get(k)
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))):
            return None
    t_pub = _num(d.get("t_pub"))
    est = {"body": body, "t": t, "t_pub": t_pub, "method": method, "phase": phase,
           **_band(d, "mass", "kg"), **_band(d, "izz", "kgm2")}
    diverged, inconsistent = d.get("diverged") is True, d.get("inconsistent") is True
    level = 2 if diverged else 1 if inconsistent else 0
    health = {"body": body, "t": t, "n_updates": n, "nis": _num(d.get("nis")),
              "diverged": diverged, "inconsistent": inconsistent, "phase": phase,
              "method": method, "status": ("ok", "inconsistent", "diverged")[level],
              "status_level": level, "lag_s": None if t_pub is None else t_pub - t}
    return est, health


class _Body:
    """The channels of one body."""

    def __init__(self, name: str, ctx: foxglove.Context) -> None:
        tp = topics_for(name)
        self.name = name
        self.frame = FrameTransformChannel(tp["frame"], context=ctx)
        self.pose = foxglove.Channel(tp["pose"], schema=POSE_VIEW, context=ctx)
        self.duty = foxglove.Channel(tp["duty"], schema=DUTY_VIEW, context=ctx)
        self.estimate = foxglove.Channel(tp["estimate"], schema=ESTIMATE_VIEW, context=ctx)
        self.health = foxglove.Channel(tp["health"], schema=HEALTH_VIEW, context=ctx)
        self.last_pose_t = -math.inf

    def close(self) -> None:
        for ch in (self.frame, self.pose, self.duty, self.estimate, self.health):
            ch.close()


class LiveView:
    """A Foxglove WebSocket server fed from Zenoh.

    Args:
        session: an open Zenoh session (:func:`common.zenoh_net.open_session`).
        host, port: where the server listens (port 0: any free port; see :attr:`port`).
        bodies: the bodies to show (names as in the keys); None: every body seen.
        pose_rate: poses forwarded per body and second (0: every pose).
    """

    def __init__(self, session: Any, *, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT,
                 bodies: Iterable[str] | None = None, prefix: str = DEFAULT_PREFIX,
                 mocap_prefix: str = DEFAULT_MOCAP_PREFIX, pose_rate: float = DEFAULT_POSE_RATE,
                 name: str = "tpods") -> None:
        self.session = session
        self.host, self._port = host, port
        self.only = None if bodies is None else [sanitize_chunk(b) for b in bodies]
        self.prefix = prefix.strip("/")
        self.mocap_prefix = mocap_prefix.strip("/")
        # 10 % slack: jittery capture times at a multiple of the rate still give every k-th pose
        self.min_dt = 0.0 if not pose_rate else 0.9 / pose_rate
        self.name = name
        self.counters: dict[str, int] = {}
        self.bodies: dict[str, _Body] = {}
        self._lock = threading.Lock()
        self._subs: list[Any] = []
        self._server: Any = None
        self._ctx = foxglove.Context()
        self._clock = foxglove.Channel(CLOCK_TOPIC, schema=CLOCK_VIEW, context=self._ctx)
        self._stats = foxglove.Channel(STATS_TOPIC, schema=STATS_VIEW, context=self._ctx)
        self._t_lab = -math.inf
        self._stop = threading.Event()
        self._stats_thread: threading.Thread | None = None

    # ------------------------------------------------------------ life cycle

    @property
    def port(self) -> int:
        return self._server.port if self._server is not None else self._port

    @property
    def url(self) -> str:
        host = "localhost" if self.host in ("127.0.0.1", "::1", "localhost") else self.host
        host = f"[{host}]" if ":" in host else host
        return f"ws://{host}:{self.port}"

    def start(self) -> LiveView:
        """:meth:`start_server`, then :meth:`subscribe`."""
        self.start_server()
        try:
            self.subscribe()
        except BaseException:
            self.close()
            raise
        return self

    def start_server(self) -> None:
        """Start the server (a port in use or a bad host: :class:`UserError`) and create the
        channels of the bodies given."""
        try:
            self._server = foxglove.start_server(
                name=self.name, host=self.host, port=self._port, context=self._ctx,
                capabilities=[foxglove.Capability.Time])
        except RuntimeError as exc:
            why = str(exc).removeprefix("FoxgloveError: ").removeprefix("Failed to bind port: ")
            hint = ("another tpods view or program holds it: choose another --port"
                    if "in use" in why else "check --host")
            raise UserError(f"cannot serve on {self.host}:{self._port} ({why}); {hint}") from None
        for b in self.only or []:
            self._body(b)
        self._stats_thread = threading.Thread(target=self._stats_loop, name="tpods-view-stats",
                                              daemon=True)
        self._stats_thread.start()

    def subscribe(self) -> None:
        """Subscribe to the poses, commands and estimates on :attr:`session`."""
        if self.only is None:
            keys = [(f"{self.mocap_prefix}/*/pose", self._on_pose),
                    (f"{self.prefix}/*/cmd", self._on_cmd),
                    (f"{self.prefix}/*/estimate", self._on_estimate)]
        else:
            keys = [k for b in self.only for k in (
                (pose_key(self.mocap_prefix, b), self._on_pose),
                (cmd_key(b, self.prefix), self._on_cmd),
                (estimate_key(b, self.prefix), self._on_estimate))]
        for key, cb in keys:
            self._subs.append(self.session.declare_subscriber(key, cb))

    def close(self) -> None:
        """Unsubscribe, stop the server; safe to call twice."""
        self._stop.set()
        for s in self._subs:
            try:
                s.undeclare()
            except Exception:  # the session may be closed already
                pass
        self._subs.clear()
        if self._stats_thread is not None:
            self._stats_thread.join(2.0)
            self._stats_thread = None
        if self._server is not None:
            self._server.stop()
            self._server = None

    def __enter__(self) -> LiveView:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------ helpers

    def _count(self, key: str, n: int = 1) -> None:
        self.counters[key] = self.counters.get(key, 0) + n

    def _body(self, name: str) -> _Body:
        b = self.bodies.get(name)
        if b is None:
            with self._lock:
                b = self.bodies.get(name)
                if b is None:
                    b = self.bodies[name] = _Body(name, self._ctx)
        return b

    def _body_of(self, key: str, prefix: str) -> str | None:
        """The body chunk of ``<prefix>/<body>/<leaf>``; None if the key is not that."""
        head = prefix + "/"
        if not key.startswith(head):
            return None
        parts = key[len(head):].split("/")
        return parts[0] if len(parts) == 2 and parts[0] else None

    # ------------------------------------------------------------ callbacks (zenoh's thread)

    def _receive(self, sample: Any, prefix: str, kind: str,
                 show: Callable[[str, bytes], None]) -> None:
        """A sample on ``<prefix>/<body>/<kind>`` to ``show(body, payload)``, counted; other
        keys and bodies skipped; an error counted, never raised (it would stop the viewer)."""
        try:
            self._count(f"{kind}_received")
            body = self._body_of(str(sample.key_expr), prefix)
            if body is None or (self.only is not None and body not in self.only):
                self._count("other_body")
                return
            show(body, sample.payload.to_bytes())
        except Exception:
            self._count("errors")

    def _on_pose(self, sample: Any) -> None:
        self._receive(sample, self.mocap_prefix, "pose", self._show_pose)

    def _on_cmd(self, sample: Any) -> None:
        self._receive(sample, self.prefix, "cmd", self._show_cmd)

    def _on_estimate(self, sample: Any) -> None:
        self._receive(sample, self.prefix, "estimate", self._show_estimate)

    def _show_pose(self, body: str, payload: bytes) -> None:
        d = decode_pose(payload, self.counters)
        if d is None:
            self._count("pose_skipped")
            return
        b = self._body(body)
        t = d["t"]
        if t < b.last_pose_t:
            if t > b.last_pose_t - CLOCK_RESET_S:
                self._count("pose_out_of_order")
                return
            # the clock went back by more than CLOCK_RESET_S: a new run
        elif t - b.last_pose_t < self.min_dt:
            self._count("pose_decimated")
            return
        b.last_pose_t = t
        log_ns = _ns(t)
        occ = d["occluded"]
        if occ:
            self._count("pose_occluded")
        else:
            qx, qy, qz, qw = yaw_quaternion(d["yaw"])
            sec, nsec = divmod(log_ns, 1_000_000_000)
            b.frame.log(FrameTransform(
                timestamp=Timestamp(sec=sec, nsec=nsec), parent_frame_id=TABLE_FRAME,
                child_frame_id=body, translation=Vector3(x=d["x"], y=d["y"], z=d["z"]),
                rotation=Quaternion(x=qx, y=qy, z=qz, w=qw)), log_time=log_ns)
        b.pose.log({"body": body, "t": t, "frame": d["frame"],
                    "x": d["x"], "y": d["y"], "z": d["z"], "yaw": d["yaw"],
                    "yaw_deg": None if occ else math.degrees(d["yaw"]), "occluded": occ},
                   log_time=log_ns)
        self._count("pose_shown")
        if t >= self._t_lab or t < self._t_lab - CLOCK_RESET_S:
            self._t_lab = t
            now = time.time()
            self._clock.log({"t_lab": t, "body": body, "frame": d["frame"], "t_host": now,
                             "lag_s": now - t}, log_time=log_ns)
            server = self._server
            if server is not None:
                server.broadcast_time(log_ns)

    def _show_cmd(self, body: str, payload: bytes) -> None:
        d = decode_command(payload, self.counters, n_channels=N_CHANNELS)
        if d is None:
            self._count("cmd_skipped")
            return
        msg = {"body": body, "t": d["t"], "seq": d["seq"], "kind": d["kind"],
               "duty": d["duty"], **{f"d{i + 1}": v for i, v in enumerate(d["duty"])}}
        self._body(body).duty.log(msg, log_time=_ns(d["t"]))
        self._count("cmd_shown")

    def _show_estimate(self, body: str, payload: bytes) -> None:
        d = decode_estimate(payload)
        views = None if d is None else estimate_view(body, d)
        if views is None:
            self._count("malformed")
            self._count("estimate_skipped")
            return
        est, health = views
        b = self._body(body)
        log_ns = _ns(est["t"])
        b.estimate.log(est, log_time=log_ns)
        b.health.log(health, log_time=log_ns)
        self._count("estimate_shown")

    def _stats_loop(self) -> None:
        while not self._stop.wait(STATS_PERIOD_S):
            self.publish_stats()

    def publish_stats(self) -> None:
        now = time.time()
        self._stats.log({"t_host": now, "bodies": sorted(self.bodies),
                         "counters": dict(self.counters)}, log_time=_ns(now))

    def status_line(self) -> str:
        c = self.counters
        bad = c.get("malformed", 0) + c.get("errors", 0)
        return (f"view: {self.url} | bodies {','.join(sorted(self.bodies)) or '-'} | "
                f"poses {c.get('pose_shown', 0)} cmds {c.get('cmd_shown', 0)} "
                f"estimates {c.get('estimate_shown', 0)} | bad {bad}")
