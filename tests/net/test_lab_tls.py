"""Mutual TLS with a lab CA and the router's access control (the shipped examples in
tpods/net_configs, certificates made at test time with openssl), and a valve link that
answers only the addresses it trusts.

On loopback: only the player's identity puts commands that reach a subscriber, only the
mocap's poses; a laptop with a valid certificate of the lab CA but another name reaches
no one; a host without a lab certificate cannot even connect. Across namespaces (marked
``netns``): the authorised flight runs with every process on TLS, while a laptop host
publishes commands and poses and tries the valve link: the estimator never takes them and
the valves never answer it (``make test-slow``)."""

from __future__ import annotations

import socket
import subprocess
import sys
import time

import pytest

from bench.emulators import EmulatedValveController
from bench.emulators.tcp import serve_tcp
from common.errors import UserError
from common.zenoh_net import open_session
from common.zenoh_router import open_router
from tests.support import lab_certs, lab_net
from tests.support.net import Collector, free_port, matching, wait_for

pytestmark = pytest.mark.skipif(lab_certs.openssl_refusal() is not None,
                                reason=str(lab_certs.openssl_refusal()))
NAMES = ("player", "mocap", "estimator", "laptop")


@pytest.fixture(scope="module")
def pki(tmp_path_factory):
    d = tmp_path_factory.mktemp("pki")
    ca = lab_certs.make_ca(d)
    lab_certs.make_cert(d, "router", ca, ("DNS:localhost", "IP:127.0.0.1",
                                          f"IP:{lab_net.LAN_ADDR['router']}"))
    for n in NAMES:
        lab_certs.make_cert(d, n, ca)
    other = d / "other"
    lab_certs.make_cert(other, "player", lab_certs.make_ca(other, "otherca"))  # not the lab's
    return d


def test_only_the_right_identities_reach_the_subscribers(pki):
    ep = f"tls/127.0.0.1:{free_port()}"
    cf = lab_certs.lab_configs(pki, ep, NAMES)
    router = open_router(zenoh_config=str(cf["router"]))
    s = {}
    try:
        s = {n: open_session(zenoh_config=str(cf[n])) for n in NAMES}
        got = Collector()
        s["estimator"].declare_subscriber("tpods/**", got)
        tries = [("player", "tpods/tpods1/cmd"), ("laptop", "tpods/tpods1/cmd"),
                 ("mocap", "tpods/mocap/tpods1/pose"), ("laptop", "tpods/mocap/tpods1/pose"),
                 ("player", "tpods/mocap/tpods1/pose"), ("mocap", "tpods/tpods1/cmd"),
                 ("estimator", "tpods/tpods1/estimate"), ("laptop", "tpods/tpods1/estimate")]
        for who, key in tries:
            pub = s[who].declare_publisher(key)
            assert wait_for(lambda p=pub: matching(p), 5.0)  # everyone may see subscribers
            pub.put(who.encode())
        # the allowed ones arrive in order; nothing else arrives after them
        assert wait_for(lambda: len(got) >= 3, 5.0)
        time.sleep(0.5)
        assert sorted(got.items) == sorted([("tpods/tpods1/cmd", b"player"),
                                            ("tpods/mocap/tpods1/pose", b"mocap"),
                                            ("tpods/tpods1/estimate", b"estimator")])
    finally:
        for x in s.values():
            x.close()
        router.close()


def test_a_host_without_a_lab_certificate_cannot_connect(pki, tmp_path):
    ep = f"tls/127.0.0.1:{free_port()}"
    cf = lab_certs.lab_configs(pki, ep, ("player",))
    router = open_router(zenoh_config=str(cf["router"]))
    try:
        stranger = tmp_path / "stranger.json5"  # a certificate of another CA
        stranger.write_text(cf["player"].read_text().replace(
            f"{pki}/player.", f"{pki}/other/player."))
        with pytest.raises(UserError, match="cannot open the zenoh session"):
            open_session(zenoh_config=str(stranger))
        plain = f"tcp/127.0.0.1:{free_port()}"  # and no plain TCP endpoint to fall back on
        with pytest.raises(UserError):
            open_session(connect=[plain], zenoh_mode="client", no_multicast=True)
    finally:
        router.close()


def test_valve_link_answers_only_trusted_addresses():
    valves = EmulatedValveController(4)
    srv = serve_tcp(valves, "127.0.0.1", 0, trust=["127.0.0.2"])
    try:
        with socket.create_connection(("127.0.0.1", srv.port), timeout=2.0) as c:
            c.sendall(b"DUTY 1 50\n")
            assert _answer(c) == b""  # closed, unanswered
        assert srv.refused == ["127.0.0.1"] and valves.duties == (0.0,) * 4
    finally:
        srv.stop()
    srv = serve_tcp(valves, "127.0.0.1", 0, trust=["127.0.0.1"])
    try:
        with socket.create_connection(("127.0.0.1", srv.port), timeout=2.0) as c:
            c.sendall(b"PING\n")
            c.settimeout(2.0)
            assert b"PONG" in c.recv(100)
    finally:
        srv.stop()


@pytest.mark.netns
@pytest.mark.flight
@pytest.mark.slow
@pytest.mark.skipif(lab_net.refusal() is not None, reason=str(lab_net.refusal()))
def test_authorised_flight_runs_and_a_laptop_reaches_neither_estimator_nor_valves(pki, tmp_path):
    from tests.support.lab_flight import VALVES_PORT, LabFlight

    ep = f"tls/{lab_net.LAN_ADDR['router']}:7447"
    cf = lab_certs.lab_configs(pki, ep, NAMES)
    laptop = (f"import time, sys\nfrom common.zenoh_net import open_session\n"
              f"s = open_session(zenoh_config={str(cf['laptop'])!r})\n"
              f"c = s.declare_publisher('tpods/tpods1/cmd')\n"
              f"p = s.declare_publisher('tpods/mocap/tpods1/pose')\n"
              f"for i in range(300):\n"
              f"    c.put(b'{{\"schema\":\"tpods.cmd/1\",\"body\":\"tpods1\",\"seq\":%d,'\n"
              f"          b'\"kind\":\"set\",\"t\":%r,\"duty\":[100,100,100,100]}}' % (i, time.time()))\n"
              f"    time.sleep(0.02)\n"
              f"print('sent', flush=True)\n")
    with lab_net.lab_net(("router", "mocap", "module", "estimator", "laptop")) as lab:
        flight = LabFlight(lab, tmp_path)
        flight.zargs = []  # each process its own identity, below
        router = flight._spawn("router", "router", [
            *_tpods("net", "router", "--zenoh-config", str(cf["router"]))],
            stdout=subprocess.PIPE)
        assert "listening on tls/" in router.stdout.readline()
        lab_module_trust = ["--trust", lab_net.LAN_ADDR["estimator"]]
        p = flight._spawn("module", "module", [
            sys.executable, "-m", "tests.support.lab_module",
            "--valves-listen", f"{lab_net.LAN_ADDR['module']}:{VALVES_PORT}",
            "--mocap-udp", f"{lab_net.CAMERA_ADDR['mocap']}:51001", *lab_module_trust,
            "--out", str(tmp_path / "module.json")], stdout=subprocess.PIPE)
        assert p.stdout.readline().startswith("ready")
        flight.zargs = ["--zenoh-config", str(cf["mocap"])]
        flight.start_bridge()
        flight.zargs = ["--zenoh-config", str(cf["estimator"])]
        flight.start_estimator()
        flight.zargs = ["--zenoh-config", str(cf["player"])]
        flight.start_player(6.0)
        time.sleep(1.5)
        fake = lab.run("laptop", [sys.executable, "-c", laptop], env=flight.env, timeout=60)
        addr = (lab_net.LAN_ADDR["module"], VALVES_PORT)
        valves_try = lab.run("laptop", [sys.executable, "-c", (
            f"import socket\ns = socket.create_connection({addr!r}, timeout=3)\n"
            "s.sendall(b'DUTY 1 100\\n'); s.settimeout(2)\n"
            "try:\n    print(repr(s.recv(100)))\nexcept ConnectionResetError:\n    print(repr(b''))"
            )], env=flight.env)
        r = flight.collect()
    assert "sent" in fake.stdout, fake.stderr
    assert valves_try.stdout.strip() == "b''", valves_try  # closed unanswered
    assert r.module["refused"] == [lab_net.LAN_ADDR["laptop"]]
    assert r.returncodes["play"] == 0 and r.play["status"] == "success", r.stderr["play"]
    assert r.returncodes["live"] == 0, r.stderr["live"]
    c = r.summary["counters"]
    n = r.play["counts"]
    assert c["cmds_rx"] == n["sent"] + n["holds"] + 1  # the player's own (and its end) only
    assert not r.summary["gaps"]  # the laptop's numbering never mixed in
    # no 100 % duty ever reached the valves (the phase-sine stays within 10..90)
    assert all(max(ch["duties"]) <= 90.0 for ch in r.module["changes"])
    # the estimator took no command of the laptop: every command it recorded is the player's
    import csv

    rows = list(csv.DictReader((r.live_dir / "commands.csv").open()))
    assert rows and all(float(x["d1"]) <= 90.0 for x in rows)
    assert not r.summary["diverged"]


def _answer(c: socket.socket) -> bytes:
    """What the server answered before closing (b"" for nothing, a reset included)."""
    c.settimeout(2.0)
    try:
        return c.recv(100)
    except ConnectionResetError:
        return b""


def _tpods(*args: str) -> list[str]:
    from tests.support.lab_flight import tpods_argv

    return tpods_argv(*args)
