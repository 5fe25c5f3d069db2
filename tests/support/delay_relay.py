"""A user-space relay that delays traffic by ``delay +- jitter`` ms (this kernel has no
``tc netem``): ``python -m tests.support.delay_relay tcp|udp LISTEN UPSTREAM``.

- ``udp``: every datagram is held an independent uniform ``delay +- jitter`` and sent
  on; with a jitter larger than the spacing of the datagrams they *reorder*. Replies go
  back the same way (one upstream socket per client address).
- ``tcp``: every chunk read is held ``delay +- jitter`` but never overtakes the chunk
  before it (a byte stream cannot reorder: the jitter then shows as bunching), both
  directions, one upstream connection per client connection.

It prints ``ready`` when it listens and, on SIGTERM, one JSON line of counts (chunks or
datagrams relayed, how many overtook an earlier one).
"""

from __future__ import annotations

import argparse
import heapq
import json
import random
import select
import signal
import socket
import sys
import threading
import time


def _addr(text: str) -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    return host, int(port)


class Scheduler:
    """Sends (time, seq, fn) items when their time comes, from one thread."""

    def __init__(self) -> None:
        self.heap: list[tuple[float, int, object]] = []
        self.cv = threading.Condition()
        self.seq = 0
        self.stop = False
        self.sent = 0
        self.reordered = 0
        self._last_seq_sent = -1
        threading.Thread(target=self._run, daemon=True).start()

    def at(self, t: float, fn) -> None:
        with self.cv:
            self.seq += 1
            heapq.heappush(self.heap, (t, self.seq, fn))
            self.cv.notify()

    def _run(self) -> None:
        while True:
            with self.cv:
                while not self.stop and (not self.heap or self.heap[0][0] > time.monotonic()):
                    self.cv.wait(None if not self.heap else max(0.0, self.heap[0][0] - time.monotonic()))
                if self.stop:
                    return
                _, seq, fn = heapq.heappop(self.heap)
            if seq < self._last_seq_sent:
                self.reordered += 1
            self._last_seq_sent = max(self._last_seq_sent, seq)
            try:
                fn()
                self.sent += 1
            except OSError:
                pass


def relay_udp(listen, upstream, delay, jitter, rng, sched, stop) -> None:
    srv = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    srv.bind(listen)
    ups: dict[tuple[str, int], socket.socket] = {}
    print("ready", flush=True)
    while not stop.is_set():
        socks = [srv, *ups.values()]
        ready, _, _ = select.select(socks, [], [], 0.1)
        for s in ready:
            try:
                data, src = s.recvfrom(65536)
            except OSError:  # ICMP unreachable from a send before the receiver bound
                continue
            d = delay + rng.uniform(-jitter, jitter)
            if s is srv:
                u = ups.get(src)
                if u is None:
                    u = ups[src] = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                    u.connect(upstream)
                sched.at(time.monotonic() + d, lambda u=u, data=data: u.send(data))
            else:
                client = next(k for k, v in ups.items() if v is s)
                sched.at(time.monotonic() + d, lambda c=client, data=data: srv.sendto(data, c))


def relay_tcp(listen, upstream, delay, jitter, rng, sched, stop) -> None:
    srv = socket.create_server(listen)
    srv.settimeout(0.1)
    print("ready", flush=True)

    def pump(a: socket.socket, b: socket.socket) -> None:
        last = 0.0
        while not stop.is_set():
            try:
                data = a.recv(65536)
            except OSError:
                data = b""
            if not data:
                sched.at(max(last, time.monotonic()), lambda: _shut(b))
                return
            last = max(last, time.monotonic() + delay + rng.uniform(-jitter, jitter))
            sched.at(last, lambda data=data: b.sendall(data))

    while not stop.is_set():
        try:
            c, _ = srv.accept()
        except TimeoutError:
            continue
        except OSError:
            return
        try:
            u = socket.create_connection(upstream, timeout=5.0)
        except OSError:
            c.close()
            continue
        for s in (c, u):
            s.settimeout(None)
            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        threading.Thread(target=pump, args=(c, u), daemon=True).start()
        threading.Thread(target=pump, args=(u, c), daemon=True).start()


def _shut(s: socket.socket) -> None:
    try:
        s.shutdown(socket.SHUT_WR)
    except OSError:
        pass


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="delay_relay")
    ap.add_argument("kind", choices=("tcp", "udp"))
    ap.add_argument("listen", metavar="HOST:PORT")
    ap.add_argument("upstream", metavar="HOST:PORT")
    ap.add_argument("--delay-ms", type=float, default=50.0)
    ap.add_argument("--jitter-ms", type=float, default=20.0)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    sched = Scheduler()
    rng = random.Random(a.seed)
    fn = relay_tcp if a.kind == "tcp" else relay_udp
    th = threading.Thread(target=fn, args=(_addr(a.listen), _addr(a.upstream), a.delay_ms / 1e3,
                                           a.jitter_ms / 1e3, rng, sched, stop), daemon=True)
    th.start()
    while not stop.wait(0.1):
        pass
    print(json.dumps({"sent": sched.sent, "reordered": sched.reordered}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
