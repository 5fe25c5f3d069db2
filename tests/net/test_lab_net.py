"""The lab of namespaces itself: hosts reach each other only over the lab network, a link
taken down cuts a host off, nftables drops at random, and nothing is left behind."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from tests.support import lab_net
from tests.support.lab_net import CAMERA_ADDR, LAN_ADDR

pytestmark = pytest.mark.netns

_REFUSED = lab_net.refusal()
needs_netns = pytest.mark.skipif(_REFUSED is not None, reason=str(_REFUSED))

# a UDP echo: the server answers each datagram; the client sends N and counts the answers
_ECHO = """
import socket, sys
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
if sys.argv[1] == "serve":
    s.bind((sys.argv[2], 9999))
    while True:
        d, a = s.recvfrom(100)
        try:
            s.sendto(d, a)
        except OSError:  # nftables dropped it on the way out (EPERM)
            pass
else:
    s.settimeout(float(sys.argv[4]))
    n = int(sys.argv[3]); got = 0
    for i in range(n):
        try:
            s.sendto(b"x", (sys.argv[2], 9999))
            s.recvfrom(100); got += 1
        except OSError:
            pass
    print(got)
"""


def _echo(lab, client: str, server_addr: str, n: int, wait_s: float = 0.05) -> int:
    p = lab.run(client, [sys.executable, "-c", _ECHO, "send", server_addr, str(n), str(wait_s)])
    assert p.returncode == 0, p.stderr
    return int(p.stdout)


@needs_netns
def test_hosts_reach_each_other_and_a_cut_link_cuts_them_off():
    with lab_net.lab_net() as lab:
        lab.spawn("router", [sys.executable, "-c", _ECHO, "serve", LAN_ADDR["router"]])
        lab.spawn("mocap", [sys.executable, "-c", _ECHO, "serve", CAMERA_ADDR["mocap"]])
        assert _wait(lambda: _echo(lab, "estimator", LAN_ADDR["router"], 5) == 5)
        assert _echo(lab, "module", CAMERA_ADDR["mocap"], 5) == 5  # the camera link
        # the machine's own namespace is not on the lab network
        assert subprocess.run([sys.executable, "-c", _ECHO, "send", LAN_ADDR["router"], "3",
                               "0.05"],
                              capture_output=True, text=True).stdout.strip() == "0"
        lab.link("estimator", False)
        assert _echo(lab, "estimator", LAN_ADDR["router"], 5) == 0
        lab.link("mocap", False)  # the lab link only: the cameras still see the module
        assert _echo(lab, "module", CAMERA_ADDR["mocap"], 5) == 5
        lab.link("estimator", True)
        assert _wait(lambda: _echo(lab, "estimator", LAN_ADDR["router"], 5) == 5)
        names = [lab.ns(h) for h in lab.hosts]
    listed = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
    assert not any(n in listed for n in names)
    links = subprocess.run(["ip", "-o", "link"], capture_output=True, text=True).stdout
    assert lab.tag not in links


@needs_netns
@pytest.mark.skipif(lab_net.nft_refusal() is not None, reason=str(lab_net.nft_refusal()))
def test_nftables_drops_the_asked_share_of_packets():
    with lab_net.lab_net(("router", "estimator")) as lab:
        lab.spawn("router", [sys.executable, "-c", _ECHO, "serve", LAN_ADDR["router"]])
        assert _wait(lambda: _echo(lab, "estimator", LAN_ADDR["router"], 5) == 5)
        lab.loss("router", 20)
        got = _echo(lab, "estimator", LAN_ADDR["router"], 400, wait_s=0.005)
        # each round trip crosses the rule twice: 0.8^2 = 64 % come back (+- 5 sigma)
        assert 0.64 * 400 - 50 < got < 0.64 * 400 + 50, got
        lab.loss("router", 0)
        assert _echo(lab, "estimator", LAN_ADDR["router"], 50) == 50


@needs_netns
def test_teardown_on_an_exception_and_leftovers_of_a_dead_process():
    with pytest.raises(RuntimeError), lab_net.lab_net(("router",)) as lab:
        names = lab.ns("router")
        raise RuntimeError("a test failing inside the lab")
    assert names not in subprocess.run(["ip", "netns", "list"], capture_output=True,
                                       text=True).stdout
    # a lab made by a process that died before its teardown (a killed xdist worker)
    code = ("import os; from tests.support import lab_net; lab = lab_net.LabNet(('router',))"
            ".build(); print(lab.ns('router'), lab.bridge, flush=True); os._exit(0)")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       env=lab_net.project_env(), timeout=60)
    ns, br = p.stdout.split()
    assert ns in subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
    gone = lab_net.clean_leftovers()
    assert ns in gone and br in gone
    assert ns not in subprocess.run(["ip", "netns", "list"], capture_output=True,
                                    text=True).stdout


def _wait(cond, timeout: float = 10.0) -> bool:
    import time

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.1)
    return False


def test_refusal_names_the_reason_when_not_root(monkeypatch):
    monkeypatch.setattr(os, "geteuid", lambda: 1000)
    assert "root" in lab_net.refusal()
