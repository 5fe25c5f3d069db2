"""A Zenoh router for a lab of several hosts: an eclipse-zenoh session in router mode.

Every host's ``tpods`` process connects to it (``--connect tcp/ROUTER:7447
--no-multicast``); it routes poses, commands and estimates between them and, given a
``--zenoh-config`` file, applies that file's TLS and access-control settings, as
``zenohd`` does. :func:`open_router` opens it from the usual Zenoh options
(:func:`common.zenoh_net.add_zenoh_options`); :func:`router_locators` reads the endpoints
it actually listens on (a ``:0`` port resolved) from its admin space;
:func:`serve_router` runs it until a stop event.

Without ``--listen`` and without a config file the router listens on Zenoh's router
default, ``tcp/[::]:7447`` (every address of the host, port 7447).
"""

from __future__ import annotations

import json
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from common.errors import UserError
from common.zenoh_net import DEFAULT_RUNTIME, RUNTIME_ENV, _get, build_config

ROUTER_MODE = "router"


@dataclass
class RouterRun:
    """What a router run saw: its id, endpoints and the peers met (zids)."""

    zid: str
    locators: list[str]
    elapsed_s: float = 0.0
    peers_seen: set[str] = field(default_factory=set)


def open_router(args: Any = None, /, **kwargs: Any):
    """A Zenoh session in router mode from the parsed Zenoh options (an
    ``argparse.Namespace`` of :func:`common.zenoh_net.add_zenoh_options` or a mapping;
    keywords of the same names override it). A ``--zenoh-mode`` other than ``router`` is a user error. Without a
    config file the admin space is readable (``zenohd``'s default too), so
    :func:`router_locators` can read the endpoints back; a config file keeps its own."""
    import zenoh  # lazy: the CLI's --help stays without zenoh

    def opt(name: str, default: Any = None) -> Any:
        if name in kwargs:
            return kwargs[name]
        return _get(args, name, default)

    mode = opt("zenoh_mode")
    if mode not in (None, ROUTER_MODE):
        raise UserError(f"a router runs in zenoh mode 'router', not {mode!r} "
                        f"(leave out --zenoh-mode)")
    os.environ.setdefault(RUNTIME_ENV, DEFAULT_RUNTIME)
    config_file = opt("zenoh_config")
    conf = build_config(connect=opt("connect"), listen=opt("listen"),
                        multicast=not opt("no_multicast", False), config_file=config_file,
                        mode=ROUTER_MODE, batch_ms=opt("zenoh_batch_ms"))
    if config_file is None:
        key, value = admin_config_json5()
        conf.insert_json5(key, value)
    try:
        return zenoh.open(conf)
    except Exception as exc:
        raise UserError(f"cannot start the zenoh router ({str(exc).splitlines()[0]})") from None


def admin_config_json5() -> tuple[str, str]:
    """The config key and JSON5 value that let a router answer reads of its admin space."""
    return "adminspace", json.dumps({"enabled": True,
                                     "permissions": {"read": True, "write": False}})


def router_locators(session, timeout_s: float = 2.0) -> list[str]:
    """The endpoints ``session`` listens on, from its admin space (``@/<zid>/router``);
    empty when the admin space does not answer within ``timeout_s`` seconds."""
    info = _router_info(session, timeout_s)
    return [] if info is None else [str(x) for x in info.get("locators", [])]


def _router_info(session, timeout_s: float) -> dict | None:
    """The router's own entry of its admin space (``@/<zid>/router``, JSON), or None when
    the admin space does not answer (switched off by a config file, a closing session)."""
    zid = str(session.info.zid())
    try:
        for reply in session.get(f"@/{zid}/router", timeout=timeout_s):
            ok = getattr(reply, "ok", None)
            if ok is not None:
                return json.loads(ok.payload.to_string())
    except Exception:  # no admin space to read
        return None
    return None


def configured_endpoints(args: Any) -> list[str]:
    """The endpoints the options ask the router to listen on (``--listen``, else the config
    file's ``listen/endpoints``): what :func:`serve_router` reports when the admin space,
    switched off by a config file, cannot say which ports were bound."""
    listen = _get(args, "listen")
    if listen:
        return list(listen)
    path = _get(args, "zenoh_config")
    if path is None:
        return []
    import zenoh

    try:
        return [str(x) for x in json.loads(zenoh.Config.from_file(str(path))
                                           .get_json("listen/endpoints"))]
    except Exception:  # the file was read once already; nothing more to say
        return []


def serve_router(args: Any, stop: threading.Event, *,
                 on_ready: Callable[[RouterRun], None] | None = None,
                 on_peers: Callable[[set[str], set[str]], None] | None = None,
                 poll_s: float = 0.5, duration_s: float | None = None) -> RouterRun:
    """Run a router until ``stop`` is set (or ``duration_s`` seconds have passed).

    ``on_ready(run)`` is called once it listens (``run.locators`` filled);
    ``on_peers(joined, left)`` every ``poll_s`` seconds in which the set of connected
    sessions (peers and clients, by zid) changed. The session is closed on every exit path.
    """
    session = open_router(args)
    t0 = time.monotonic()
    try:
        run = RouterRun(zid=str(session.info.zid()),
                        locators=router_locators(session) or configured_endpoints(args))
        if on_ready is not None:
            on_ready(run)
        known: dict[str, str] = {}  # zid -> its description
        seen: dict[str, str] = {}
        t_end = None if duration_s is None else t0 + duration_s
        while not stop.is_set():
            wait = poll_s if t_end is None else min(poll_s, t_end - time.monotonic())
            if wait <= 0:
                break
            stop.wait(wait)
            now = _connected(session)
            # by zid: a poll the admin space did not answer in time names the same session
            # by its zid alone, which must not count as a second session
            for zid, desc in now.items():
                if desc != zid or zid not in seen:
                    seen[zid] = desc
            run.peers_seen = set(seen.values())
            if now.keys() != known.keys():
                if on_peers is not None:
                    on_peers({now[z] for z in now.keys() - known.keys()},
                             {known[z] for z in known.keys() - now.keys()})
                known = now
        run.elapsed_s = time.monotonic() - t0
        return run
    finally:
        session.close()


def _connected(session, timeout_s: float = 1.0) -> dict[str, str]:
    """The sessions this router is connected to: zid -> ``ZID (KIND from ADDRESS)`` from its
    admin space, or zid -> zid when the admin space does not answer."""
    info = _router_info(session, timeout_s)
    if info is not None:
        out = {}
        for s in info.get("sessions", []):
            links = s.get("links") or [{}]
            zid = str(s.get("peer"))
            out[zid] = f"{zid} ({s.get('whatami', '?')} from {links[0].get('dst', '?')})"
        return out
    try:
        return {str(z): str(z) for z in session.info.peers_zid()}
    except Exception:
        return {}
