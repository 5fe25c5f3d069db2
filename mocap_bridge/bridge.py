"""The bridge: pose samples from a source onto Zenoh, one key per rigid body.

Per body it drops repeated (or older) frame numbers, counts frame gaps, publishes
occluded bodies as ``occluded: true`` (never as zeros), maps the mocap axes to the
table frame and computes the yaw. Statistics go to ``<prefix>/stats`` every second and
the bridge holds a liveliness token ``<prefix>/bridge/<zenoh id>`` while it runs.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

import zenoh

from common.wire import ENCODING, encode_pose, pose_key
from mocap_bridge.pose import AxisMap, PoseSample
from mocap_bridge.stats import BodyStats, BridgeStats, encode_stats

DEFAULT_PREFIX = "tpods/mocap"
RESTART_FRAMES = 100_000
"""A frame number this far below the last one means the mocap restarted: accept it."""


class Bridge:
    """Publish pose samples on Zenoh.

    Args:
        session: an open ``zenoh.Session`` (see :func:`common.zenoh_net.open_session`).
        prefix: key prefix; poses go to ``<prefix>/<body>/pose``, stats to ``<prefix>/stats``.
        axis_map: mocap-to-table mapping and yaw projection (ignored for sources whose
            poses are already in the table frame: replay, sim).
        congestion: ``"block"`` (default: nothing is dropped inside Zenoh; a slow network
            shows up as UDP frame gaps, which are counted) or ``"drop"``.
        stats_period_s: period of the stats messages and of ``on_stats`` calls.
        on_stats: called with each stats snapshot (e.g. to print the console line).
        express: send each pose in its own socket write instead of letting Zenoh batch
            what is queued. Off by default: at 20,000 poses/s express doubled the
            bridge's CPU per pose and its latency tail went up to 170 ms (``make bench``).
    """

    def __init__(self, session: Any, prefix: str = DEFAULT_PREFIX, axis_map: AxisMap | None = None,
                 congestion: str = "block", stats_period_s: float = 1.0,
                 on_stats: Callable[[dict[str, Any]], None] | None = None,
                 express: bool = False) -> None:
        self.session = session
        self.prefix = prefix.strip("/")
        if not self.prefix:
            raise ValueError("the key prefix must not be empty")
        self.axis_map = axis_map or AxisMap()
        self._table_map = AxisMap(projection=self.axis_map.projection)
        if congestion not in ("block", "drop"):
            raise ValueError(f"congestion must be 'block' or 'drop', got {congestion!r}")
        self._cc = zenoh.CongestionControl.BLOCK if congestion == "block" else zenoh.CongestionControl.DROP
        self._encoding = zenoh.Encoding(ENCODING)
        self.stats_period_s = stats_period_s
        self.on_stats = on_stats
        self.express = express
        self.stats = BridgeStats()
        self.stats_key = f"{self.prefix}/stats"
        self._pubs: dict[str, Any] = {}
        self._token = None
        self._stats_thread: threading.Thread | None = None
        self._stats_stop = threading.Event()
        self.last_snapshot: dict[str, Any] | None = None

    # -------------------------------------------------------------- lifecycle

    def start(self, source_name: str = "", source_counters: dict[str, int] | None = None) -> None:
        """Declare the liveliness token and start the stats thread."""
        self.stats.source = source_name
        if source_counters is not None:
            self.stats.source_counters = source_counters
        zid = str(self.session.zid())
        self._token = self.session.liveliness().declare_token(f"{self.prefix}/bridge/{zid}")
        self._stats_thread = threading.Thread(target=self._stats_loop, name="mocap-stats", daemon=True)
        self._stats_thread.start()

    def close(self) -> None:
        """Publish a last stats message, stop the thread, undeclare everything."""
        self._stats_stop.set()
        if self._stats_thread is not None:
            self._stats_thread.join(timeout=5.0)
            self._stats_thread = None
            self.publish_stats()
        for pub in self._pubs.values():
            try:
                pub.undeclare()
            except Exception:
                pass
        self._pubs.clear()
        if self._token is not None:
            try:
                self._token.undeclare()
            except Exception:
                pass
            self._token = None

    def __enter__(self) -> Bridge:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _stats_loop(self) -> None:
        while not self._stats_stop.wait(self.stats_period_s):
            try:
                self.publish_stats()
            except Exception:  # a closed session during shutdown: stop quietly
                if self._stats_stop.is_set() or self.session.is_closed():
                    return
                raise

    def publish_stats(self) -> dict[str, Any]:
        snap = self.stats.snapshot()
        self.last_snapshot = snap
        if not self.session.is_closed():
            self.session.put(self.stats_key, encode_stats(snap), encoding=self._encoding)
        if self.on_stats is not None:
            self.on_stats(snap)
        return snap

    def wait_for_subscriber(self, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` until a subscriber matches ``<prefix>/*/pose``."""
        probe = self.session.declare_publisher(f"{self.prefix}/*/pose")
        try:
            deadline = time.monotonic() + timeout_s
            while True:
                ms = probe.matching_status
                if bool(getattr(ms, "matching", ms)):
                    return True
                if time.monotonic() >= deadline:
                    return False
                time.sleep(0.02)
        finally:
            probe.undeclare()

    # -------------------------------------------------------------- hot path

    def _body(self, name: str) -> tuple[BodyStats, Any]:
        st = self.stats.bodies.get(name)
        if st is None:
            st = self.stats.bodies[name] = BodyStats()
        pub = self._pubs.get(name)
        if pub is None:
            pub = self._pubs[name] = self.session.declare_publisher(
                pose_key(self.prefix, name), encoding=self._encoding, congestion_control=self._cc,
                express=self.express)
        return st, pub

    def publish(self, batch: list[PoseSample], in_table_frame: bool = False) -> int:
        """Publish one batch of samples; returns how many were published."""
        amap = self._table_map if in_table_frame else self.axis_map
        bodies = self.stats.bodies
        n = 0
        out = []
        for s in batch:
            st = bodies.get(s.body)
            pub = self._pubs.get(s.body)
            if st is None or pub is None:
                st, pub = self._body(s.body)
            last = st.last_frame
            f = s.frame
            if last is not None:
                if f <= last:
                    if last - f < RESTART_FRAMES:
                        st.duplicates += 1
                        continue
                    st.restarts += 1
                elif f > last + 1:
                    st.gaps += f - last - 1
            st.last_frame = f
            st.last_t = s.t
            if s.occluded:
                pose = None
                st.occluded += 1
            else:
                pose = amap.apply(s)
            out.append((pub, encode_pose(s.body, f, s.t, s.t_recv, pose, s.t_src)))
            st.published += 1
            n += 1
        # Encode everything first, then put back to back: Zenoh's tx thread then finds
        # the whole batch queued and writes it to the socket in one go.
        for pub, payload in out:
            pub.put(payload)
        return n

    def run(self, source: Any, stop: threading.Event | None = None,
            duration_s: float | None = None) -> BridgeStats:
        """Publish everything ``source`` yields until it ends, ``stop`` is set or
        ``duration_s`` elapses. Starts and closes the bridge (stats, liveliness)."""
        stop = stop or threading.Event()
        timer = None
        if duration_s is not None:
            timer = threading.Timer(duration_s, stop.set)
            timer.daemon = True
            timer.start()
        self.start(getattr(source, "name", ""), getattr(source, "counters", None))
        in_table = bool(getattr(source, "in_table_frame", False))
        try:
            for batch in source.batches(stop):
                self.publish(batch, in_table)
        finally:
            if timer is not None:
                timer.cancel()
            self.close()
        return self.stats

