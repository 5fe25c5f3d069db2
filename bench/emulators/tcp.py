"""Serve a byte-stream emulator on a loopback TCP port (``socket://127.0.0.1:PORT``).

Same emulator interface as :mod:`bench.emulators.pty` (``receive`` / ``tick``); one
client at a time, like a module's Wi-Fi serial bridge. A new connection replaces
the previous one. Given ``trust`` (addresses), a connection from any other address is
closed at once, unanswered (counted in ``refused``): on a lab network only the player's
host may drive the valves.
"""

from __future__ import annotations

import select
import socket
import time
from collections.abc import Iterable

from bench.emulators.pty import Emulator, EmulatorServer


class TcpServer(EmulatorServer):
    """A running TCP server: ``url`` is ``socket://HOST:PORT``; ``stop()`` ends it."""

    def __init__(self, emulator: Emulator, host: str = "127.0.0.1", port: int = 0,
                 max_idle_s: float = 0.02, trust: Iterable[str] | None = None) -> None:
        self.emulator = emulator
        self.trust = None if trust is None else frozenset(trust)
        self.refused: list[str] = []
        """Addresses whose connections were closed unanswered (not trusted)."""
        self._max_idle_s = max_idle_s
        self._srv = socket.create_server((host, port))
        self._srv.setblocking(False)
        self.host, self.port = self._srv.getsockname()[:2]
        self.url = f"socket://{self.host}:{self.port}"
        self._conn: socket.socket | None = None
        self._start(f"tcp-{self.port}")

    def _send(self, data: bytes) -> None:
        if self._conn is None or not data:
            return
        try:
            self._conn.sendall(data)
        except OSError:
            self._drop()

    def _drop(self) -> None:
        if self._conn is not None:
            self._conn.close()
            self._conn = None

    def _loop(self) -> None:
        next_tick: float | None = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            if next_tick is not None and now >= next_tick:
                out, next_tick = self.emulator.tick(now)
                self._send(out)
                now = time.monotonic()
            wait = self._max_idle_s if next_tick is None else min(self._max_idle_s, max(0.0, next_tick - now))
            socks = [self._srv] + ([self._conn] if self._conn is not None else [])
            try:
                ready, _, _ = select.select(socks, [], [], wait)
            except (OSError, ValueError):
                if self._stop.is_set():
                    return
                continue
            if self._srv in ready:
                try:
                    conn, peer = self._srv.accept()
                except OSError:
                    continue
                if self.trust is not None and peer[0] not in self.trust:
                    self.refused.append(peer[0])
                    conn.close()
                    continue
                self._drop()
                conn.setblocking(True)
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                self._conn = conn
            if self._conn is not None and self._conn in ready:
                try:
                    data = self._conn.recv(4096)
                except OSError:
                    data = b""
                if not data:
                    self._drop()
                    continue
                self._send(self.emulator.receive(data, time.monotonic()))
                next_tick = time.monotonic()

    def _release(self) -> None:
        """Close the connection and the listening socket."""
        self._drop()
        self._srv.close()


def serve_tcp(emulator: Emulator, host: str = "127.0.0.1", port: int = 0,
              trust: Iterable[str] | None = None) -> TcpServer:
    """Serve ``emulator`` on ``host:port`` (0: a free port); returns the server (``.url``).
    ``trust``: the only client addresses answered (None: any)."""
    return TcpServer(emulator, host, port, trust=trust)
