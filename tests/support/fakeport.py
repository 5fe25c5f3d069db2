"""A scripted serial port for exact expected-exchange tests (pymeasure style).

``ScriptedPort([(sent, reply), ...])``: each write must equal the next ``sent``
bytes exactly; its ``reply`` bytes then become readable. ``feed()`` adds
unsolicited bytes (continuous print).
"""

from __future__ import annotations

import threading
import time


class ScriptedPort:
    def __init__(self, script: list[tuple[bytes, bytes]] | None = None) -> None:
        self.script = list(script or [])
        self.rx = bytearray()
        self.written: list[bytes] = []
        self.timeout = 0.02
        self.closed = False
        self.name = "scripted"
        self._lock = threading.Lock()

    def write(self, data: bytes) -> int:
        data = bytes(data)
        with self._lock:
            self.written.append(data)
            assert self.script, f"unexpected write {data!r}"
            expected, reply = self.script.pop(0)
            assert data == expected, f"sent {data!r}, expected {expected!r}"
            self.rx += reply
        return len(data)

    def feed(self, data: bytes) -> None:
        with self._lock:
            self.rx += data

    @property
    def in_waiting(self) -> int:
        return len(self.rx)

    def read(self, n: int = 1) -> bytes:
        with self._lock:
            if self.rx:
                out = bytes(self.rx[:n])
                del self.rx[:n]
                return out
        time.sleep(min(self.timeout, 0.005))
        return b""

    def reset_input_buffer(self) -> None:
        with self._lock:
            self.rx.clear()

    def flush(self) -> None:
        pass

    def close(self) -> None:
        self.closed = True

    def done(self) -> bool:
        return not self.script
