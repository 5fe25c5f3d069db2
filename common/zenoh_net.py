"""One way to reach Zenoh for every ``tpods`` command that talks Zenoh.

:func:`add_zenoh_options` adds ``--connect EP`` / ``--listen EP`` (repeatable),
``--no-multicast``, ``--zenoh-config FILE``, ``--zenoh-mode`` and ``--zenoh-batch-ms``;
:func:`open_session` builds the configuration and opens the session;
:func:`wait_matching` waits for the subscribers of publishers (a player that starts before
its estimator).

With none of the options (the one-machine case) the session is a *peer* that listens on
``tcp/127.0.0.1:7447`` (the local hub; if another tpods process already holds it,
that is fine), connects to that same hub, and also listens on a random loopback port;
gossip scouting then meshes every local peer directly. No router and no multicast are
needed; multicast scouting stays on so peers on other hosts of the same LAN are found
too, unless ``--no-multicast``. ``TPODS_ZENOH_HUB`` overrides the hub endpoint.

With ``--connect``/``--listen`` only the given endpoints are used (typical lab set-up:
``--connect tcp/ROUTER_HOST:7447`` to a ``zenohd`` router). ``--zenoh-config FILE`` is
loaded first (TLS certificates, access control, anything zenoh supports) and the
command-line options are applied on top of it.

Latency: Zenoh's default holds messages up to 1 ms to fill a batch once its transmit
queue is congested (``transport/link/tx/queue/batching/time_limit``). Every message of
this toolkit is a small real-time sample (a pose, a command, an estimate) and the hold
was the largest part of the bridge's latency tail at 20,000 poses/s (p99 2.7-3.0 ms with
it, 1.6 ms without, ``make bench``), so tpods sessions set it to 0 ms: whatever is
queued still goes out in one batch, nothing waits for more. A ``--zenoh-config`` file
keeps its own value unless ``--zenoh-batch-ms`` is given.

Receive threads: Zenoh's receive runtime has two worker threads by default; both run the
Python callbacks of the subscribers and take turns on the interpreter lock. On the 2-core
bench machine one worker gave a shorter tail for the same load (raw put at 20,000/s,
p99 0.8-1.4 ms against 1.4-4.2 ms, three pairs; bridge runs pooled p99 1.12 against
1.40 ms, eight pairs) and the same maximum rate (77,000-87,000/s). So before its first
session a tpods process sets ``ZENOH_RUNTIME`` to ``(rx: (worker_threads: 1))`` unless the
environment already sets ``ZENOH_RUNTIME`` (Zenoh reads it once per process).

Receive callbacks: a plain Python callable given to ``declare_subscriber`` runs in a
Python thread zenoh-python starts for it (``indirect``), one hand-over per sample.
:func:`direct_callback` runs it on Zenoh's receive thread itself, for callbacks that never
block (a queue put): no hand-over, and poses and commands keep their arrival order.
zenoh-python takes the interpreter lock there with ``PyGILState_Ensure``/``Release``
around each call, and on a thread Python did not start CPython makes a new thread state
at each Ensure and deletes it at the Release that brings the thread's count back to
zero; :func:`keep_thread_state` holds one Ensure for the thread's lifetime instead. A
direct subscriber at 20,000 samples/s then used 0.7 instead of 2.3 CPU-seconds per 5 s,
and the bridge bench's p99 (whose measuring subscriber is direct) went from 2.7-3.6 to
1.4-1.6 ms (two pairs of runs, ``benchmarks/bench_mocap.py``).
"""

from __future__ import annotations

import argparse
import ctypes
import json
import os
import threading
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from common.argtypes import int_at_least
from common.errors import UserError

DEFAULT_HUB = "tcp/127.0.0.1:7447"
MODES = ("peer", "client", "router")
DEFAULT_BATCH_MS = 0
"""Zenoh's transmit batching time limit for tpods sessions, ms (zenoh's own default: 1)."""
_BATCH_KEY = "transport/link/tx/queue/batching/time_limit"
RUNTIME_ENV = "ZENOH_RUNTIME"
DEFAULT_RUNTIME = "(rx: (worker_threads: 1))"
"""Zenoh runtime settings for tpods processes (see the module notes); a user's own
``ZENOH_RUNTIME`` wins."""


def add_zenoh_options(parser: argparse.ArgumentParser) -> None:
    """Add the Zenoh connection options (same on every command)."""
    g = parser.add_argument_group(
        "zenoh", "how to reach Zenoh (default: an embedded peer meshing with the other "
                 "tpods processes of this machine; no router needed)")
    g.add_argument("--connect", action="append", default=None, metavar="EP",
                   help="endpoint to connect to, e.g. tcp/192.168.1.10:7447 (repeatable)")
    g.add_argument("--listen", action="append", default=None, metavar="EP",
                   help="endpoint to listen on, e.g. tcp/0.0.0.0:7448 (repeatable)")
    g.add_argument("--no-multicast", action="store_true",
                   help="disable multicast scouting (use explicit endpoints)")
    g.add_argument("--zenoh-config", metavar="FILE", default=None,
                   help="zenoh JSON5 config file (TLS, access control, ...); options above "
                        "override it")
    g.add_argument("--zenoh-mode", choices=MODES, default=None,
                   help="zenoh mode (default peer; 'client' to go through a router only)")
    g.add_argument("--zenoh-batch-ms", type=int_at_least(0), default=None, metavar="MS",
                   help=f"longest time zenoh may hold a message to fill a batch when its "
                        f"transmit queue is congested, integer ms (default {DEFAULT_BATCH_MS} "
                        f"for the lowest latency; zenoh's own default is 1)")


def loopback_endpoint() -> str:
    """A Zenoh TCP endpoint on a free loopback port, ``tcp/127.0.0.1:PORT``: the hub of a
    private mesh of a few processes on this machine (benchmarks, examples)."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def _get(src: Any, name: str, default: Any = None) -> Any:
    if src is None:
        return default
    if isinstance(src, Mapping):
        return src.get(name, default)
    return getattr(src, name, default)


def build_config(connect: list[str] | None = None, listen: list[str] | None = None,
                 multicast: bool = True, config_file: str | Path | None = None,
                 mode: str | None = None, batch_ms: int | None = None):
    """The ``zenoh.Config`` for these options (see the module docstring).

    ``batch_ms``: Zenoh's transmit batching time limit (integer ms); None means
    :data:`DEFAULT_BATCH_MS`, or the config file's own value when a file is given.
    """
    import zenoh  # lazy: this module builds the CLI's options; tpods --help stays without zenoh

    if config_file is not None:
        path = Path(config_file)
        if not path.is_file():
            raise UserError(f"{path}: zenoh config file not found")
        try:
            conf = zenoh.Config.from_file(str(path))
        except Exception as exc:  # zenoh raises its own error type with a long message
            raise UserError(f"{path}: not a valid zenoh config ({str(exc).splitlines()[0]})") from None
    else:
        conf = zenoh.Config()
    if mode is not None:
        if mode not in MODES:
            raise UserError(f"zenoh mode must be one of {', '.join(MODES)}, got {mode!r}")
        conf.insert_json5("mode", json.dumps(mode))
    elif config_file is None:
        conf.insert_json5("mode", '"peer"')
    for ep in (connect or []) + (listen or []):
        if not isinstance(ep, str) or "/" not in ep:
            raise UserError(f"bad zenoh endpoint {ep!r} (expected e.g. tcp/127.0.0.1:7447)")
    if batch_ms is not None and (isinstance(batch_ms, bool) or not isinstance(batch_ms, int)
                                 or batch_ms < 0):
        raise UserError(f"zenoh batch time must be a whole number of ms >= 0, got {batch_ms!r}")
    explicit = bool(connect) or bool(listen)
    try:
        if connect:
            conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
        if listen:
            conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
        if not explicit and config_file is None and (mode or "peer") == "peer":
            hub = os.environ.get("TPODS_ZENOH_HUB", DEFAULT_HUB)
            host = hub.rsplit(":", 1)[0]
            conf.insert_json5("listen/endpoints", json.dumps([hub, f"{host}:0"]))
            conf.insert_json5("listen/exit_on_failure", "false")
            conf.insert_json5("connect/endpoints", json.dumps([hub]))
            conf.insert_json5("connect/exit_on_failure", "false")
            conf.insert_json5("connect/timeout_ms", "0")
        if not multicast:
            conf.insert_json5("scouting/multicast/enabled", "false")
        if batch_ms is not None or config_file is None:
            conf.insert_json5(_BATCH_KEY, str(DEFAULT_BATCH_MS if batch_ms is None else batch_ms))
    except Exception as exc:
        raise UserError(f"bad zenoh option ({str(exc).splitlines()[0]})") from None
    return conf


def open_session(args: Any = None, /, **kwargs: Any):
    """Open a Zenoh session from parsed options or keywords.

    ``args`` is an ``argparse.Namespace`` from :func:`add_zenoh_options` or a mapping;
    keywords (``connect``, ``listen``, ``multicast`` or ``no_multicast``,
    ``zenoh_config``, ``zenoh_mode``, ``zenoh_batch_ms``) override it. Raises :class:`UserError` (one line)
    when the configuration is bad or the session cannot open.
    """
    os.environ.setdefault(RUNTIME_ENV, DEFAULT_RUNTIME)  # before zenoh starts its runtimes
    import zenoh  # lazy: this module builds the CLI's options; tpods --help stays without zenoh

    def opt(name: str, default: Any = None) -> Any:
        return kwargs[name] if name in kwargs else _get(args, name, default)

    multicast = opt("multicast", None)
    if multicast is None:
        multicast = not opt("no_multicast", False)
    conf = build_config(connect=opt("connect"), listen=opt("listen"), multicast=bool(multicast),
                        config_file=opt("zenoh_config", opt("config_file")),
                        mode=opt("zenoh_mode", opt("mode")),
                        batch_ms=opt("zenoh_batch_ms", opt("batch_ms")))
    try:
        return zenoh.open(conf)
    except Exception as exc:
        raise UserError(f"cannot open the zenoh session ({str(exc).splitlines()[0]})") from None


def wait_matching(publishers: list[Any], timeout_s: float, poll_s: float = 0.01) -> bool:
    """Until every publisher has a matching subscriber (``matching_status``), at most
    ``timeout_s`` seconds; whether they all have one."""
    deadline = time.monotonic() + timeout_s
    while True:
        if all(bool(getattr(p.matching_status, "matching", p.matching_status)) for p in publishers):
            return True
        if time.monotonic() >= deadline:
            return False
        time.sleep(poll_s)


_KEPT: set[int] = set()
"""Threads whose Python thread state :func:`keep_thread_state` holds."""


def keep_thread_state(fn: Callable[[Any], None]) -> Callable[[Any], None]:
    """``fn`` as a Zenoh callback that keeps its receiving thread's Python thread state
    (see the module doc): the first call on a thread takes one ``PyGILState_Ensure``
    that is never released, so later calls on that thread reuse its state."""
    kept = _KEPT
    ident = threading.get_ident

    def callback(sample: Any) -> None:
        if ident() not in kept:
            ctypes.pythonapi.PyGILState_Ensure()  # the lock is held: only counts up
            kept.add(ident())
        fn(sample)

    return callback


def direct_callback(fn: Callable[[Any], None]):
    """``fn`` as a handler that runs on Zenoh's receive thread (:func:`keep_thread_state`
    kept): only for callbacks that never block."""
    import zenoh  # lazy: see open_session

    return zenoh.handlers.Callback(keep_thread_state(fn), indirect=False)
