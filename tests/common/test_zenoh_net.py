"""Zenoh options: explicit endpoints, the default local hub, config files, errors."""

from __future__ import annotations

import argparse
import json

import pytest

from common.errors import UserError
from common.zenoh_net import add_zenoh_options, build_config, open_session
from tests.support.net import Collector, free_port, subscribe_ready, wait_for


def _parse(argv):
    p = argparse.ArgumentParser()
    add_zenoh_options(p)
    return p.parse_args(argv)


def test_options_parse_and_build_the_config():
    a = _parse(["--connect", "tcp/10.0.0.1:7447", "--connect", "tcp/10.0.0.2:7447",
                "--listen", "tcp/0.0.0.0:7448", "--no-multicast", "--zenoh-mode", "client"])
    assert a.connect == ["tcp/10.0.0.1:7447", "tcp/10.0.0.2:7447"] and a.no_multicast
    c = build_config(connect=a.connect, listen=a.listen, multicast=False, mode=a.zenoh_mode)
    assert json.loads(c.get_json("connect/endpoints")) == a.connect
    assert json.loads(c.get_json("listen/endpoints")) == ["tcp/0.0.0.0:7448"]
    assert json.loads(c.get_json("scouting/multicast/enabled")) is False
    assert json.loads(c.get_json("mode")) == "client"
    d = build_config()  # the one-machine default: peer on the local hub, multicast left on
    assert json.loads(d.get_json("mode")) == "peer"
    assert json.loads(d.get_json("connect/endpoints")) == ["tcp/127.0.0.1:7447"]
    assert json.loads(d.get_json("listen/endpoints")) == ["tcp/127.0.0.1:7447", "tcp/127.0.0.1:0"]
    assert json.loads(d.get_json("scouting/multicast/enabled")) in (None, True)


def test_config_file_is_passed_through_and_options_override_it(tmp_path):
    f = tmp_path / "z.json5"
    f.write_text('{ mode: "peer", connect: { endpoints: ["tcp/127.0.0.1:1"] },'
                 ' scouting: { multicast: { enabled: false } } }')
    c = build_config(config_file=f)
    assert json.loads(c.get_json("connect/endpoints")) == ["tcp/127.0.0.1:1"]
    assert json.loads(c.get_json("listen/endpoints")) != ["tcp/127.0.0.1:7447", "tcp/127.0.0.1:0"]
    c2 = build_config(config_file=f, connect=["tcp/127.0.0.1:2"])
    assert json.loads(c2.get_json("connect/endpoints")) == ["tcp/127.0.0.1:2"]


def test_batching_limit_defaults_to_zero_and_a_config_file_keeps_its_own(tmp_path):
    key = "transport/link/tx/queue/batching/time_limit"
    assert json.loads(build_config().get_json(key)) == 0
    assert json.loads(build_config(batch_ms=3).get_json(key)) == 3
    assert _parse(["--zenoh-batch-ms", "2"]).zenoh_batch_ms == 2
    f = tmp_path / "z.json5"
    f.write_text('{ transport: { link: { tx: { queue: { batching: { time_limit: 5 } } } } } }')
    assert json.loads(build_config(config_file=f).get_json(key)) == 5
    assert json.loads(build_config(config_file=f, batch_ms=0).get_json(key)) == 0
    for bad in (["--zenoh-batch-ms", "-1"], ["--zenoh-batch-ms", "0.5"]):
        with pytest.raises(SystemExit):
            _parse(bad)
    with pytest.raises(UserError, match="whole number"):
        build_config(batch_ms=-2)


def test_bad_options_are_one_line_user_errors(tmp_path):
    with pytest.raises(UserError, match="not found"):
        build_config(config_file=tmp_path / "missing.json5")
    bad = tmp_path / "bad.json5"
    bad.write_text("{ mode: ")
    with pytest.raises(UserError, match="not a valid zenoh config"):
        build_config(config_file=bad)
    with pytest.raises(UserError, match="endpoint"):
        build_config(connect=["localhost"])
    with pytest.raises(UserError, match="mode"):
        build_config(mode="server")


def test_default_sessions_find_each_other_without_multicast(monkeypatch):
    """With no endpoint options, local peers mesh through the hub (here on a free port)."""
    hub = f"tcp/127.0.0.1:{free_port()}"
    monkeypatch.setenv("TPODS_ZENOH_HUB", hub)
    ns = _parse(["--no-multicast"])
    a = open_session(ns)
    b = open_session(ns)
    c = open_session(ns)
    try:
        assert wait_for(lambda: len(b.info.peers_zid()) >= 2 and len(c.info.peers_zid()) >= 2, 15.0)
        col = Collector()
        sub = subscribe_ready(b, c, "demo/**", col)  # b publishes, c subscribes: not the hub
        b.put("demo/x", b"hello")  # b and c are not the hub
        assert wait_for(lambda: len(col) == 1, 5.0)
        sub.undeclare()
    finally:
        for s in (c, b, a):
            s.close()


_RX_PROBE = """
import os, time
from common.zenoh_net import open_session
ep = "tcp/127.0.0.1:%d"
a = open_session(listen=[ep], no_multicast=True)
b = open_session(connect=[ep], no_multicast=True)
time.sleep(0.5)
names = [open(f"/proc/self/task/{t}/comm").read().strip() for t in os.listdir("/proc/self/task")]
print(sum(n.startswith("rx-") for n in names))
a.close(); b.close()
"""


@pytest.mark.parametrize("user_value,expected", [(None, 1), ("(rx: (worker_threads: 3))", 3)])
def test_one_receive_thread_unless_the_user_sets_zenoh_runtime(user_value, expected):
    import os
    import subprocess
    import sys
    from pathlib import Path

    if not Path("/proc/self/task").is_dir():
        pytest.skip("thread names need /proc")
    env = {k: v for k, v in os.environ.items() if k != "ZENOH_RUNTIME"}
    if user_value is not None:
        env["ZENOH_RUNTIME"] = user_value
    out = subprocess.run([sys.executable, "-c", _RX_PROBE % free_port()], env=env,
                         capture_output=True, text=True, timeout=60, cwd=Path(__file__).parents[2])
    assert out.returncode == 0, out.stderr[-2000:]
    assert int(out.stdout.strip().splitlines()[-1]) == expected



_KEPT_SCRIPT = """
import json, sys, threading, time
import zenoh
from common.zenoh_net import keep_thread_state, open_session
ep = sys.argv[1]
pub = open_session(listen=[ep], no_multicast=True)
sub = open_session(connect=[ep], no_multicast=True)
local, seen = threading.local(), {"plain": [], "kept": []}
def count(name):
    def cb(sample):
        n = getattr(local, name, 0)
        setattr(local, name, n + 1)
        seen[name].append(n)
    return cb
for name, cb in (("plain", count("plain")), ("kept", keep_thread_state(count("kept")))):
    s = sub.declare_subscriber("lanes/" + name, zenoh.handlers.Callback(cb, indirect=False))
    p = pub.declare_publisher("lanes/" + name)
    deadline = time.monotonic() + 10
    while not p.matching_status.matching and time.monotonic() < deadline:
        time.sleep(0.01)
    for k in range(20):
        p.put(b"x")
    while len(seen[name]) < 20 and time.monotonic() < deadline:
        time.sleep(0.01)
print(json.dumps(seen))
sub.close(); pub.close()
"""


def test_a_kept_callback_reuses_its_thread_state_across_samples():
    """A direct callback (``indirect=False``) runs on Zenoh's own thread; without
    keep_thread_state CPython makes and deletes a thread state around every call (a
    thread-local value never survives to the next sample), with it the state lives on
    (~20 us less per sample). In a fresh process: a kept receive thread stays kept for
    every later callback of the process, so the plain callback goes first."""
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-c", _KEPT_SCRIPT, f"tcp/127.0.0.1:{free_port()}"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr[-2000:]
    seen = json.loads(r.stdout.strip().splitlines()[-1])
    assert seen["plain"] == [0] * 20
    assert seen["kept"] == list(range(20))
