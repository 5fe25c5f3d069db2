"""Zenoh streams in MCAP: write them as they arrive, read them back (also after a kill).

An MCAP file (https://mcap.dev, the ``mcap`` library) holds one channel per Zenoh key
(topic = the key, message encoding ``json``, the payload bytes as received) with the JSON
Schema of its payloads (schema encoding ``jsonschema``, from :mod:`common.wire_schemas`,
chosen by the first payload's ``schema`` field; schema id 0 for a payload of no known
schema). A payload that is not a JSON object is kept too, on a channel of the same topic
with message encoding ``application/octet-stream`` (a recording is a fixture: a malformed
message must replay as it came).

- ``log_time``: the host time the message was received (ns since the Unix epoch);
  ``publish_time``: the message's own time where it has one (a pose's capture time ``t``,
  a command's ``t``, an estimate's ``t_pub``; any other payload's ``t``), else the
  receive time; ``sequence``: the message's number on its channel (from 1).
- **Off the receiving thread.** :meth:`McapLog.write` only appends the payload and its
  receive time to a queue (no parsing, no lock, no file work: it runs in Zenoh callbacks
  and, for a session's own publications, inside ``put``); a background thread parses,
  adds and flushes. The queue is bounded without dropping anything: past
  ``max_pending`` messages the writing thread does the work itself (:meth:`McapLog.drain`).
  :meth:`McapLog.flush` and :meth:`McapLog.close` write everything queued first. With
  ``flush_every_s=0`` (no background thread) every write is written at once.
- **Or in a process of its own:** :class:`common.mcap.process.McapProcessLog` (same file,
  same interface) for a recording beside a latency-critical loop (``tpods estimate live``).
- **Written to survive a kill.** The file is chunked (LZ4) with small chunks: a chunk is
  closed and handed to the operating system every ``flush_every_s`` (0.05 s) by the
  background thread, and whenever it grows past ``chunk_size``. SIGKILL then loses at
  most the messages of the last ~0.05 s (tested: at most 0.1 s); the file has no summary
  or footer, which the ``mcap`` library's seeking reader needs: :func:`read_messages`
  (and ``tpods replay``) fall back to a linear read of every complete chunk
  (``mcap.reader.NonSeekingReader``, stopping at the cut). A clean :meth:`McapLog.close`
  writes the summary (statistics, chunk and message indexes) and the footer.
- Metadata records: ``tpods`` (what wrote the file, when, settings) at the start and
  ``tpods.end`` (status, counters) at a clean end.
"""

from __future__ import annotations

import contextlib
import json
import math
import struct
import threading
import time
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader, make_reader
from mcap.writer import CompressionType, Writer

from common import __version__
from common.errors import UserError
from common.wire import CMD_SCHEMA, EST_SCHEMA, SCHEMA
from common.wire_schemas import SCHEMAS, schema_bytes
from common.zenoh_net import direct_callback

MESSAGE_ENCODING = "json"
SCHEMA_ENCODING = "jsonschema"
RAW_ENCODING = "application/octet-stream"
"""Message encoding of the channel that keeps a key's payloads that are not JSON objects."""
FLUSH_EVERY_S = 0.05
CHUNK_SIZE = 64 * 1024
MAX_PENDING = 20_000
"""Messages queued for the background writer before :meth:`McapLog.write` writes them itself."""
WRITE_SLICE = 64
"""Messages the background writer adds between two yields of the GIL (latency of the
threads that receive and publish)."""
LIBRARY = f"tpods {__version__}"

_OWN_TIME = {SCHEMA: "t", CMD_SCHEMA: "t", EST_SCHEMA: "t_pub"}
_MAX_NS = 2**64 - 1


def _compression() -> CompressionType:
    try:
        import lz4.frame  # noqa: F401  # lazy: an mcap dependency; without it chunks stay uncompressed
    except ImportError:  # pragma: no cover
        return CompressionType.NONE
    return CompressionType.LZ4


def seconds_to_ns(t: Any) -> int | None:
    """``t`` seconds as integer nanoseconds, or None if it is not a finite time >= 0."""
    if isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t) or t < 0:
        return None
    ns = round(t * 1e9)
    return ns if ns <= _MAX_NS else None


def own_time_ns(d: dict[str, Any]) -> int | None:
    """A decoded payload's own time (see the module doc), ns, or None."""
    return seconds_to_ns(d.get(_OWN_TIME.get(d.get("schema"), "t")))


class McapLog:
    """An MCAP file of Zenoh messages, written as they arrive (thread-safe).

    ``write(key, payload)`` from any thread (Zenoh callbacks); ``close()`` at the end
    (or use it as a context manager). ``meta``: string values for the ``tpods`` metadata
    record. Counters: ``messages``, ``raw`` (payloads that are not JSON objects)."""

    def __init__(self, path: str | Path, *, meta: dict[str, Any] | None = None,
                 flush_every_s: float = FLUSH_EVERY_S, chunk_size: int = CHUNK_SIZE,
                 stream: IO[bytes] | None = None, max_pending: int = MAX_PENDING) -> None:
        self.path = Path(path)
        if stream is None:
            try:
                stream = open(self.path, "wb")  # noqa: SIM115 (closed in close())
            except OSError as exc:
                raise UserError(f"{self.path}: cannot write ({exc.strerror})") from None
            self._own_stream = True
        else:
            self._own_stream = False
        self._f = stream
        self._w = Writer(stream, chunk_size=chunk_size, compression=_compression(),
                         enable_data_crcs=True)
        self._w.start(profile="", library=LIBRARY)
        self._w.add_metadata("tpods", {k: _text(v) for k, v in {
            "software": LIBRARY, "created_unix_s": f"{time.time():.3f}", **(meta or {})}.items()})
        self._schemas: dict[str, int] = {}
        self._channels: dict[tuple[str, bool], int] = {}
        self._seq: dict[int, int] = {}
        self.counters = {"messages": 0, "raw": 0}
        self.closed = False
        self._dirty = False
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._pending: deque[tuple[str, bytes, int, int | None]] = deque()
        self._max_pending = max(1, int(max_pending))
        self._flusher = None
        if flush_every_s > 0:
            self._flusher = threading.Thread(target=self._flush_loop, args=(flush_every_s,),
                                             name="mcap-flush", daemon=True)
            self._flusher.start()

    @property
    def topics(self) -> set[str]:
        """The keys logged so far."""
        return {k for k, _raw in self._channels}

    # ------------------------------------------------------------------ writing

    def _schema_id(self, name: Any) -> int:
        if not isinstance(name, str) or name not in SCHEMAS:
            return 0
        sid = self._schemas.get(name)
        if sid is None:
            sid = self._schemas[name] = self._w.register_schema(name, SCHEMA_ENCODING,
                                                                schema_bytes(name))
        return sid

    def _channel(self, key: str, d: dict[str, Any] | None) -> int:
        raw = d is None
        cid = self._channels.get((key, raw))
        if cid is None:
            if raw:
                cid = self._w.register_channel(key, RAW_ENCODING, 0,
                                               {"note": "payloads that are not JSON objects, as received"})
            else:
                cid = self._w.register_channel(key, MESSAGE_ENCODING, self._schema_id(d.get("schema")))
            self._channels[(key, raw)] = cid
        return cid

    def write(self, key: str, payload: bytes | bytearray | memoryview, log_time_ns: int | None = None,
              publish_time_ns: int | None = None) -> None:
        """Log one message of ``key``; ``log_time_ns``: its receive time (default: now).

        Queues it for the background writer (see the module doc); never drops it."""
        if log_time_ns is None:
            log_time_ns = time.time_ns()
        self._pending.append((key, bytes(payload), log_time_ns, publish_time_ns))  # atomic
        if self._flusher is None or len(self._pending) >= self._max_pending:
            self.drain()

    def drain(self, limit: int | None = None, count_errors: bool = False) -> int:
        """Add up to ``limit`` (default: all) queued messages to the file, in arrival order;
        returns how many. A message the file refuses (disk full, file closed) raises, or
        with ``count_errors`` counts as ``write_errors`` (the background writer)."""
        n = 0
        pending = self._pending
        with self._lock:
            while pending and (limit is None or n < limit):
                key, data, log_ns, pub_ns = pending.popleft()
                n += 1
                if self.closed:
                    continue
                try:
                    self._add(key, data, log_ns, pub_ns)
                except (OSError, ValueError):
                    if not count_errors:
                        raise
                    self.counters["write_errors"] = self.counters.get("write_errors", 0) + 1
        return n

    def _add(self, key: str, data: bytes, log_time_ns: int, publish_time_ns: int | None) -> None:
        """Parse and add one message (under the lock)."""
        try:
            d = json.loads(data)
        except (ValueError, UnicodeDecodeError):
            d = None
        if not isinstance(d, dict):
            d = None
        if publish_time_ns is None:
            publish_time_ns = own_time_ns(d) if d is not None else None
            if publish_time_ns is None:
                publish_time_ns = log_time_ns
        cid = self._channel(str(key), d)
        seq = self._seq[cid] = self._seq.get(cid, 0) + 1
        self._w.add_message(cid, log_time=log_time_ns, data=data,
                            publish_time=publish_time_ns, sequence=seq & 0xFFFFFFFF)
        self.counters["messages"] += 1
        if d is None:
            self.counters["raw"] += 1
        self._dirty = True

    def flush(self) -> None:
        """Write what is queued, close the chunk in progress and hand everything to the
        operating system."""
        self.drain()
        with self._lock:
            if not self.closed and self._dirty:
                self._w.flush()
                self._dirty = False

    def _flush_loop(self, every: float) -> None:
        while not self._stop.wait(every):
            try:
                # in slices, yielding the GIL between them: a receiving thread waits at
                # most one slice (~0.5 ms), not the whole batch
                while self.drain(WRITE_SLICE, count_errors=True) == WRITE_SLICE:
                    time.sleep(0)
                self.flush()
            except (OSError, ValueError):  # disk full, file closed: the writer sees it next
                return

    def close(self, status: str = "complete", extra: dict[str, Any] | None = None) -> None:
        """Write the ``tpods.end`` metadata, the summary and the footer; close the file."""
        self._stop.set()
        if self._flusher is not None and self._flusher is not threading.current_thread():
            self._flusher.join(timeout=5.0)
        with contextlib.suppress(OSError, ValueError):
            self.drain()  # everything received is written before the end
        with self._lock:
            if self.closed:
                return
            self.closed = True
            try:
                self._w.add_metadata("tpods.end", {k: _text(v) for k, v in {
                    "status": status, "ended_unix_s": f"{time.time():.3f}",
                    **{k: v for k, v in self.counters.items()}, **(extra or {})}.items()})
                self._w.finish()
            finally:
                if self._own_stream:
                    with contextlib.suppress(OSError):
                        self._f.close()

    def __enter__(self) -> McapLog:
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        self.close("complete" if exc_type is None else "incomplete")


def _text(v: Any) -> str:
    return v if isinstance(v, str) else json.dumps(v, default=str)


def subscribe(session: Any, key: str, log: McapLog):
    """Declare a Zenoh subscriber on ``key`` (a key expression) logging every sample
    under its own key; returns it (undeclare when done)."""
    def on_sample(sample: Any) -> None:
        t = time.time_ns()
        try:
            log.write(str(sample.key_expr), sample.payload.to_bytes(), t)
        except (OSError, ValueError):  # disk full, file closed: counted, session kept alive
            log.counters["write_errors"] = log.counters.get("write_errors", 0) + 1

    try:
        return session.declare_subscriber(key, direct_callback(on_sample))
    except Exception as exc:
        raise UserError(f"cannot subscribe to {key!r} ({str(exc).splitlines()[0]})") from None


# ------------------------------------------------------------------ reading


@dataclass(frozen=True)
class McapMessage:
    """One message read back: its topic (the Zenoh key), schema name ('' for none),
    message encoding, times (ns), sequence and payload bytes."""

    topic: str
    schema: str
    encoding: str
    log_time: int
    publish_time: int
    sequence: int
    data: bytes


@dataclass
class McapRead:
    """What :func:`read_mcap` found: the messages, whether the file ended cleanly (summary
    and footer present), and why reading stopped early, if it did."""

    messages: list[McapMessage]
    complete: bool
    stopped_by: str = ""


def _message(schema, channel, message) -> McapMessage:
    return McapMessage(channel.topic, schema.name if schema is not None else "",
                       channel.message_encoding, message.log_time, message.publish_time,
                       message.sequence, bytes(message.data))


def has_summary(path: str | Path) -> bool:
    """Whether the file ends with a footer and a summary (written by a clean close)."""
    try:
        with open(path, "rb") as f:
            return make_reader(f).get_summary() is not None
    except (McapError, struct.error, OSError, ValueError, StopIteration):
        return False


def end_status(path: str | Path) -> str | None:
    """The ``status`` of a file's ``tpods.end`` metadata (``complete``, ``incomplete``, ...);
    None when the file was cut (no summary: killed mid-run) or ends without one."""
    if not has_summary(path):
        return None
    try:
        with open(path, "rb") as f:
            for rec in make_reader(f).iter_metadata():
                if rec.name == "tpods.end":
                    return str(rec.metadata.get("status", ""))
    except (McapError, struct.error, OSError, ValueError, StopIteration):
        return None
    return None


def iter_messages(path: str | Path, *, validate_crcs: bool = True,
                  status: McapRead | None = None) -> Iterator[McapMessage]:
    """Every message of an MCAP file, in log-time order when the file has its summary, in
    file order otherwise (a file cut by a kill: every complete chunk, then stop; our
    recorders write in arrival order). ``status``, when given, receives ``complete`` and
    ``stopped_by``. A file that is not MCAP at all is a :class:`UserError`."""
    path = Path(path)
    st = status if status is not None else McapRead([], False)
    try:
        f = open(path, "rb")  # noqa: SIM115
    except OSError as exc:
        raise UserError(f"{path}: cannot read ({exc.strerror})") from None
    with f:
        if f.read(8) != b"\x89MCAP0\r\n":
            raise UserError(f"{path}: not an MCAP file")
        f.seek(0)
        st.complete = has_summary(path)
        if st.complete:
            reader = make_reader(f, validate_crcs=validate_crcs)
            for m in reader.iter_messages(log_time_order=True):
                yield _message(*m)
            return
        it = NonSeekingReader(f, validate_crcs=validate_crcs).iter_messages(log_time_order=False)
        while True:
            try:
                m = next(it)
            except StopIteration:
                return
            except (McapError, struct.error, ValueError) as exc:  # the cut of a kill
                st.stopped_by = f"{type(exc).__name__}: {exc}".rstrip(": ")
                return
            yield _message(*m)


def read_mcap(path: str | Path, *, validate_crcs: bool = True) -> McapRead:
    """All messages of a file (see :func:`iter_messages`), recovered after a kill."""
    st = McapRead([], False)
    st.messages = list(iter_messages(path, validate_crcs=validate_crcs, status=st))
    return st
