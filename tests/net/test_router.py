"""``tpods net router`` on loopback: a real eclipse-zenoh router routes between two clients,
prints its endpoints, stops cleanly on SIGINT and SIGTERM; bad options are one line."""

from __future__ import annotations

import signal
import subprocess
import threading
import time

import pytest

from common.errors import UserError
from common.zenoh_net import open_session
from common.zenoh_router import open_router, router_locators, serve_router
from tests.support.net import Collector, free_port, matching, wait_for


def _clients(ep: str, n: int = 2):
    return [open_session(connect=[ep], no_multicast=True, zenoh_mode="client") for _ in range(n)]


def test_router_routes_between_clients_and_reports_its_port():
    """Two clients that only know the router exchange a sample through it; ``:0`` is
    reported as the port actually bound."""
    router = open_router(listen=["tcp/127.0.0.1:0"], no_multicast=True)
    try:
        (ep,) = router_locators(router)
        assert ep.startswith("tcp/127.0.0.1:") and not ep.endswith(":0")
        a, b = _clients(ep)
        try:
            got = Collector()
            b.declare_subscriber("tpods/t/cmd", got)
            pub = a.declare_publisher("tpods/t/cmd")
            assert wait_for(lambda: matching(pub), 10.0)
            pub.put(b"hello")
            assert wait_for(lambda: got.of_key("cmd") == [b"hello"], 5.0)
        finally:
            b.close()
            a.close()
    finally:
        router.close()


def test_serve_router_sees_sessions_join_and_leave():
    stop = threading.Event()
    port = free_port()
    events: list[tuple[set[str], set[str]]] = []
    ready: list = []
    th = threading.Thread(target=lambda: ready.append(serve_router(
        {"listen": [f"tcp/127.0.0.1:{port}"], "no_multicast": True}, stop,
        on_peers=lambda j, gone: events.append((j, gone)), poll_s=0.05)), daemon=True)
    th.start()
    try:
        assert wait_for(lambda: _port_open(port), 10.0)
        (c,) = _clients(f"tcp/127.0.0.1:{port}", 1)
        zid = str(c.info.zid()).lstrip("0")
        assert wait_for(lambda: any(zid in z for j, _ in events for z in j), 5.0)
        c.close()
        assert wait_for(lambda: any(zid in z for _, g in events for z in g), 15.0)
    finally:
        stop.set()
        th.join(10.0)
    assert not th.is_alive()
    assert any(zid in z and "client" in z for z in ready[0].peers_seen)


def _port_open(port: int) -> bool:
    import socket

    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) == 0


def test_router_refuses_another_mode():
    with pytest.raises(UserError, match="router"):
        open_router(zenoh_mode="peer", listen=["tcp/127.0.0.1:0"])


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_cli_router_prints_endpoints_and_stops_on_signal(tpods_exe, sig):
    port = free_port()
    p = subprocess.Popen([tpods_exe, "net", "router", "--listen", f"tcp/127.0.0.1:{port}",
                          "--no-multicast"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True)
    try:
        line = p.stdout.readline()
        assert f"listening on tcp/127.0.0.1:{port}" in line, line + p.stderr.read()
        (c,) = _clients(f"tcp/127.0.0.1:{port}", 1)
        time.sleep(0.7)  # one poll of the router's session list
        c.close()
        p.send_signal(sig)
        out, err = p.communicate(timeout=15)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 0, err
    assert "router: stopped after" in out and "1 sessions met" in out
    assert "joined" in err and "Traceback" not in err


@pytest.mark.parametrize("argv, words", [
    (["--zenoh-mode", "client"], "zenoh mode 'router'"),
    (["--listen", "tcp/192.0.2.1:1"], "cannot start the zenoh router"),
    (["--zenoh-config", "/nonexistent.json5"], "zenoh config file not found"),
    (["--listen", "nonsense"], "bad zenoh endpoint"),
])
def test_cli_router_user_errors_are_one_line(tpods_exe, argv, words):
    p = subprocess.run([tpods_exe, "net", "router", "--no-multicast", *argv],
                       capture_output=True, text=True, timeout=30)
    assert p.returncode == 2
    assert words in p.stderr and len(p.stderr.strip().splitlines()) == 1, p.stderr
