"""Publish an MCAP recording back onto Zenoh with its timing (``tpods replay``).

Every message goes out on its channel's topic (the Zenoh key it was recorded from,
optionally remapped: :func:`remapper`) with its payload bytes unchanged, in log-time
order (file order for a file cut by a kill, which our recorders write in arrival order),
at the recorded pace divided by ``speed`` (0: as fast as possible). JSON channels are
published with encoding ``application/json`` (:data:`common.wire.ENCODING`), the
``application/octet-stream`` channel of malformed payloads as such. Publishers use
congestion control ``block``: nothing is dropped silently.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from common.errors import UserError
from common.mcap.log import RAW_ENCODING, McapRead, iter_messages
from common.wire import ENCODING


def remapper(prefixes: list[str] | None) -> Callable[[str], str]:
    """The key remapping of ``--prefix``: ``OLD=NEW`` replaces a leading ``OLD`` (whole
    chunks) with ``NEW``; a plain ``NEW`` is put in front of every key. Several are tried
    in order, the first that applies wins."""
    rules: list[tuple[str | None, str]] = []
    for p in prefixes or []:
        old, eq, new = p.partition("=")
        if eq:
            old, new = old.strip("/"), new.strip("/")
            if not old:
                raise UserError(f"--prefix {p!r}: nothing before '='; give OLD=NEW, e.g. tpods=lab2")
            rules.append((old, new))
        else:
            if not p.strip("/"):
                raise UserError("--prefix must not be empty")
            rules.append((None, p.strip("/")))

    def remap(key: str) -> str:
        for old, new in rules:
            if old is None:
                return f"{new}/{key}"
            if key == old or key.startswith(old + "/"):
                rest = key[len(old):].lstrip("/")
                return "/".join(x for x in (new, rest) if x)
        return key
    return remap


def _matching(pub: Any) -> bool:
    ms = pub.matching_status
    return bool(getattr(ms, "matching", ms))


def replay(session: Any, path: str | Path, *, speed: float = 1.0,
           remap: Callable[[str], str] | None = None, stop: threading.Event | None = None,
           wait_subscriber_s: float = 0.0, on_progress: Callable[[dict[str, Any]], None] | None = None,
           progress_period_s: float = 1.0) -> dict[str, Any]:
    """Publish the messages of ``path`` on ``session``; returns counters (``published``,
    ``keys``, ``complete``: whether the file had its summary, ``stopped_by``: why reading
    a cut file ended, ``span_s``: recorded time covered, ``elapsed_s``)."""
    import zenoh  # lazy: common stays importable without a Zenoh session

    if speed < 0:
        raise UserError(f"--speed must be >= 0, got {speed:g}")
    stop = stop or threading.Event()
    remap = remap or (lambda k: k)
    enc = {True: zenoh.Encoding(ENCODING), False: zenoh.Encoding(RAW_ENCODING)}
    pubs: dict[tuple[str, bool], Any] = {}
    st = McapRead([], False)
    n = 0
    first_lt = last_lt = None
    t_start = time.monotonic()
    next_progress = t_start + progress_period_s
    waited = False
    try:
        for m in iter_messages(path, status=st):
            if stop.is_set():
                break
            key = remap(m.topic)
            is_json = m.encoding != RAW_ENCODING
            pub = pubs.get((key, is_json))
            if pub is None:
                try:
                    pub = pubs[(key, is_json)] = session.declare_publisher(
                        key, encoding=enc[is_json], congestion_control=zenoh.CongestionControl.BLOCK,
                        express=True)
                except Exception as exc:
                    raise UserError(f"{path}: cannot publish on {key!r} "
                                    f"({str(exc).splitlines()[0]})") from None
            if not waited:
                waited = True
                deadline = time.monotonic() + wait_subscriber_s
                while wait_subscriber_s > 0 and not _matching(pub) and time.monotonic() < deadline:
                    if stop.wait(0.01):
                        break
                t_start = time.monotonic()
            if first_lt is None:
                first_lt = m.log_time
            if speed > 0:
                due = t_start + (m.log_time - first_lt) * 1e-9 / speed
                while not stop.is_set():
                    wait = due - time.monotonic()
                    if wait <= 0:
                        break
                    stop.wait(min(wait, 0.5))
                if stop.is_set():
                    break
            pub.put(m.data)
            n += 1
            last_lt = m.log_time
            if on_progress is not None and time.monotonic() >= next_progress:
                next_progress = time.monotonic() + progress_period_s
                on_progress({"published": n, "t_s": (last_lt - first_lt) * 1e-9})
    finally:
        for p in pubs.values():
            with contextlib.suppress(Exception):
                p.undeclare()
    return {"published": n, "keys": sorted({k for k, _ in pubs}), "complete": st.complete,
            "stopped_by": st.stopped_by,
            "span_s": 0.0 if first_lt is None else (last_lt - first_lt) * 1e-9,
            "elapsed_s": time.monotonic() - t_start}
