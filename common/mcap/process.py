"""An MCAP recording written by a process of its own (``tpods estimate live --mcap``).

:class:`common.mcap.log.McapLog` parses and adds every message in a thread of the
recording process. In the live estimator that thread took the interpreter lock for
about 84 us of Python per message (json.loads, the ``mcap`` writer, chunk compression)
at 2,000 messages/s, and the estimator's pose-to-estimate p99 went from 2.9 to 5.8 ms
(``make bench``: ``bench_live``). :class:`McapProcessLog` keeps the same interface but
only queues ``(key, payload, receive time)`` in the caller's process; the queue goes to a
spawned writer process every :data:`FEED_EVERY_S` (one pipe write per batch), from a
feeder thread woken when the caller's loop is idle (:meth:`McapProcessLog.idle`: a live
estimator between two poses) or else once the queue is one and a half periods old, and
the writer process runs an ordinary ``McapLog`` on it, so the file is the same: channels,
schemas, sequences, times, ``tpods`` and ``tpods.end`` metadata.

- The writer needs only ``mcap`` and this package (no Zenoh, no estimator): it starts in
  a few tenths of a second while the caller goes on; what arrives meanwhile waits in
  the pipe.
- Killed caller: the writer sees the pipe close, writes everything it received with
  status ``incomplete`` and closes the file cleanly (summary and footer). What the
  caller had queued but not yet handed over is lost: at most 2.5 :data:`FEED_EVERY_S`.
- Writer that dies: the next hand-over or :meth:`McapProcessLog.close` finds it gone;
  ``close`` raises :class:`common.errors.UserError` naming the file and the exit code
  (the file keeps what was written up to the last chunk).
"""

from __future__ import annotations

import multiprocessing as mp
import time
from pathlib import Path
from typing import Any

from common.errors import UserError
from common.process_feeder import CLOSE_TIMEOUT_S, BatchFeeder

FEED_EVERY_S = 0.02
"""The caller's queue goes to the writer process at this period."""


def _writer_main(path: str, meta: dict[str, Any], conn, flush_every_s: float) -> None:
    """The writer process: batches from ``conn`` into an McapLog, flushed every
    ``flush_every_s``; ``("close", status, extra)`` ends it (replying with the counters),
    and so does the pipe closing (status ``incomplete``)."""
    from common.lowprio import LagGuard, background

    background()  # a live estimator in the caller takes a core at once when it wakes
    guard = LagGuard()
    from common.mcap.log import McapLog

    log = McapLog(path, meta=meta, flush_every_s=0)
    status, extra, reply = "incomplete", {"note": "the recording process ended without "
                                                  "closing the file (killed?)"}, False
    next_flush = time.monotonic() + flush_every_s
    try:
        while True:
            if conn.poll(max(0.0, next_flush - time.monotonic())):
                try:
                    msg = conn.recv()
                except (EOFError, OSError):
                    break
                if msg[0] == "batch":
                    guard.check(msg[2] if len(msg) > 2 else None)
                    for item in msg[1]:
                        log.write(*item)
                elif msg[0] == "flush":
                    log.flush()
                    conn.send(("flushed",))
                elif msg[0] == "close":
                    status, extra, reply = msg[1], msg[2], True
                    break
            if time.monotonic() >= next_flush:
                log.flush()
                next_flush = time.monotonic() + flush_every_s
    finally:
        log.close(status, extra)
        if reply:
            conn.send(("closed", dict(log.counters), sorted(log.topics)))
        conn.close()


class McapProcessLog:
    """:class:`common.mcap.log.McapLog`'s interface (``write``, ``flush``, ``close``,
    ``counters``, ``topics``, ``path``, ``closed``, context manager), written by a
    process of its own (see the module doc). ``counters`` hold the writer's figures
    after :meth:`close` (``messages``, ``raw``) and the caller's ``write_errors``."""

    def __init__(self, path: str | Path, *, meta: dict[str, Any] | None = None,
                 flush_every_s: float = 0.05) -> None:
        self.path = Path(path)
        try:  # a bad path is the user's error, said now and in one line
            self.path.open("wb").close()
        except OSError as exc:
            raise UserError(f"{self.path}: cannot write ({exc.strerror})") from None
        self.counters: dict[str, int] = {"messages": 0, "raw": 0}
        self.closed = False
        self._keys: set[str] = set()
        ctx = mp.get_context("spawn")
        conn, child = ctx.Pipe()
        self._proc = ctx.Process(target=_writer_main, name="mcap-writer", daemon=True,
                                 args=(str(self.path), meta or {}, child, flush_every_s))
        self._proc.start()
        child.close()
        self._feed = BatchFeeder(conn, self._proc, "mcap-feed", FEED_EVERY_S)

    @property
    def topics(self) -> set[str]:
        """The keys logged so far."""
        return set(self._keys)

    def write(self, key: str, payload: bytes | bytearray | memoryview,
              log_time_ns: int | None = None, publish_time_ns: int | None = None) -> None:
        """Queue one message of ``key`` (``log_time_ns``: its receive time, default now)."""
        if log_time_ns is None:
            log_time_ns = time.time_ns()
        self._keys.add(key)
        self._feed.queue.append((key, bytes(payload), log_time_ns, publish_time_ns))  # atomic

    def idle(self) -> None:
        """The caller's loop is idle (a live estimator between two poses): the feeder
        thread may hand the queue over now (:meth:`common.process_feeder.BatchFeeder.idle`)."""
        self._feed.idle()

    def flush(self) -> None:
        """Hand everything queued to the writer and wait until it is in the file."""
        self._feed.ask(("flush",), CLOSE_TIMEOUT_S)

    def close(self, status: str = "complete", extra: dict[str, Any] | None = None) -> None:
        """Hand over what is queued, let the writer write the ``tpods.end`` metadata, the
        summary and the footer, and wait for it; raises UserError if the writer died."""
        if self.closed:
            return
        self.closed = True
        reply = self._feed.finish(status, extra)
        if self._feed.lost:
            self.counters["write_errors"] = self.counters.get("write_errors", 0) + self._feed.lost
        if reply is None or reply[0] != "closed":
            raise UserError(f"{self.path}: the MCAP writer process ended early (exit code "
                            f"{self._proc.exitcode}); the file holds what it wrote before")
        self.counters.update(reply[1])

    def __enter__(self) -> McapProcessLog:
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        self.close("complete" if exc_type is None else "incomplete")
