"""Network helpers: free loopback ports, waiting, in-process Zenoh peers (explicit
tcp/127.0.0.1 endpoints, multicast scouting off), a collecting subscriber and a bridge
running in a thread. The ``zenoh_pair`` fixture is in tests/conftest.py."""

from __future__ import annotations

import socket
import threading
import time


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_for(cond, timeout: float = 10.0, period: float = 0.01) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(period)
    return cond()


class Collector:
    """Thread-safe list of (key, payload bytes) from a Zenoh subscriber."""

    def __init__(self) -> None:
        self.items: list[tuple[str, bytes]] = []
        self.lock = threading.Lock()

    def __call__(self, sample) -> None:
        with self.lock:
            self.items.append((str(sample.key_expr), sample.payload.to_bytes()))

    def of_key(self, suffix: str) -> list[bytes]:
        with self.lock:
            return [p for k, p in self.items if k.endswith(suffix)]

    def __len__(self) -> int:
        with self.lock:
            return len(self.items)


def matching(publisher) -> bool:
    """Whether a subscriber matches (``matching_status`` is a MatchingStatus object)."""
    ms = publisher.matching_status
    return bool(getattr(ms, "matching", ms))


def subscribe_ready(pub_session, sub_session, key: str, collector: Collector):
    """Declare a subscriber and wait until the publisher side can see it."""
    s = sub_session.declare_subscriber(key, collector)
    probe = pub_session.declare_publisher(key.replace("**", "probe").replace("*", "probe"))
    assert wait_for(lambda: matching(probe), 10.0), "subscriber never matched"
    probe.undeclare()
    return s


class RunningBridge:
    """Run ``Bridge.run(source)`` in a thread; ``stop()`` ends it (with a timeout)."""

    def __init__(self, bridge, source) -> None:
        self.bridge = bridge
        self.source = source
        self.stop_event = threading.Event()
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        try:
            self.bridge.run(self.source, stop=self.stop_event)
        except BaseException as exc:  # surfaced in stop()
            self.error = exc

    def __enter__(self):
        self.thread.start()
        return self

    def stop(self) -> None:
        self.stop_event.set()
        self.thread.join(timeout=10.0)
        assert not self.thread.is_alive(), "bridge thread did not stop"
        self.source.close()
        if self.error is not None:
            raise self.error

    def __exit__(self, *exc) -> None:
        self.stop()
