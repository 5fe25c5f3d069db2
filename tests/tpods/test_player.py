"""The input player on an emulated valve controller (pty): schedule, files, messages, safety."""

from __future__ import annotations

import json
import threading
import time

import numpy as np
import pandas as pd
import pytest

from bench.emulators import EmulatedValveController, serve_pty
from bench.valves import ValveController
from common.errors import UserError
from estimator.plant.inputs import phase_sine
from tpods.clock import LabClock
from tpods.player import decode_command, encode_command, play


@pytest.fixture
def valves():
    emu = EmulatedValveController(4)
    srv = serve_pty(emu)
    try:
        yield emu, srv.path
    finally:
        srv.stop()


def _decode_all(msgs):
    out = [decode_command(m) for m in msgs]
    assert all(o is not None for o in out)
    return out


def test_command_payload_round_trip_and_refusals():
    d = decode_command(encode_command("mod 1", 7, 1763770000.123456, [50, 64.1, 0, 12.5], "hold"))
    assert d == {"schema": "tpods.cmd/1", "body": "mod 1", "seq": 7, "kind": "hold",
                 "t": 1763770000.123456, "duty": [50.0, 64.1, 0.0, 12.5]}
    counters: dict = {}
    bad = [b"not json", b"[1,2]", b'{"schema":"tpods.pose/1"}',
           b'{"schema":"tpods.cmd/1","seq":1,"t":1.0,"duty":[1,2,3]}',          # 3 channels
           b'{"schema":"tpods.cmd/1","seq":1,"t":1.0,"duty":[1,2,3,101]}',      # > 100 %
           b'{"schema":"tpods.cmd/1","seq":1,"t":NaN,"duty":[1,2,3,4]}',        # NaN time
           b'{"schema":"tpods.cmd/1","seq":true,"t":1.0,"duty":[1,2,3,4]}',     # bool seq
           b'{"schema":"tpods.cmd/1","seq":1,"t":1.0,"duty":[1,2,3,4],"kind":"x"}',
           b'\xff\xfe']
    for b in bad:
        assert decode_command(b, counters) is None, b
    assert counters["malformed"] == len(bad)


def test_play_sends_records_and_announces_every_command(valves, tmp_path):
    emu, path = valves
    cmd_t, duty = phase_sine(1.0, 20.0)
    msgs: list[bytes] = []
    clock = LabClock(2.0, time.time())
    with ValveController(path) as vc:
        res = play(vc, cmd_t, duty, clock=clock, publish=msgs.append, out_dir=tmp_path,
                   heartbeat_s=0.1)
    assert res.status == "success" and res.final_state == (0.0, 0.0, 0.0, 0.0)
    # the controller saw exactly the sequence (to the protocol's 3 decimals), then closed
    got = [c.duties for c in emu.log if c.cause == "command"]
    assert np.allclose(got[:len(duty)], np.round(duty, 3), atol=1e-9)
    assert not any(emu.duties)
    df = pd.read_csv(tmp_path / "commands.csv")
    assert len(df) == len(cmd_t) and np.allclose(df.iloc[:, 1:], duty, atol=1e-5)
    assert not df.iloc[-1, 1:].any()  # the closing row
    # times follow the schedule on the lab clock (sent within a few lab ms)
    assert np.all(np.abs(df["t"].to_numpy() - cmd_t) < 0.05)
    meta = json.loads((tmp_path / "run.json").read_text())
    assert meta["status"] == "success" and meta["valves_closed_confirmed"] is True
    assert meta["time_scale"] == 2.0 and meta["counts"]["sent"] == len(cmd_t)
    dec = _decode_all(msgs)
    assert [m["seq"] for m in dec] == list(range(1, len(dec) + 1))
    sets = [m for m in dec if m["kind"] != "hold"]
    assert len(sets) == len(cmd_t) and dec[-1]["kind"] == "end" and not any(dec[-1]["duty"])
    assert np.allclose([m["t"] for m in sets], df["t"] + meta["t0_lab"], atol=1e-6)


def test_hold_messages_while_nothing_changes(valves):
    emu, path = valves
    msgs: list[bytes] = []
    cmd_t = np.array([0.0, 0.6, 0.7])
    duty = np.array([[30.0, 0, 30, 0], [0, 30, 0, 30], [0, 0, 0, 0]])
    with ValveController(path) as vc:
        play(vc, cmd_t, duty, publish=msgs.append, heartbeat_s=0.1, lead_s=0.05)
    dec = _decode_all(msgs)
    holds = [m for m in dec if m["kind"] == "hold" and m["t"] > dec[1]["t"]]
    assert 4 <= len(holds) <= 7  # ~every 0.1 s through the 0.6 s hold
    assert all(m["duty"] == [30.0, 0.0, 30.0, 0.0] for m in holds)
    assert np.all(np.diff([m["t"] for m in dec]) > 0)


def test_refused_sequence_opens_nothing(valves, tmp_path):
    emu, path = valves
    with ValveController(path, duty_limits=(10, 90)) as vc:
        with pytest.raises(UserError, match="outside the allowed"):
            play(vc, [0.0, 1.0], [[50, 50, 95, 0], [0, 0, 0, 0]], out_dir=tmp_path)
        with pytest.raises(UserError, match="channels"):
            play(vc, [0.0, 1.0], [[50, 50, 50], [0, 0, 0]])
    assert all(not any(c.duties) for c in emu.log)


@pytest.mark.parametrize("how", ["stop", "interrupt", "publish-error"])
def test_every_exit_path_closes_the_valves(valves, tmp_path, how):
    emu, path = valves
    cmd_t, duty = phase_sine(3.0, 20.0)
    stop = threading.Event()
    n = {"k": 0}

    def publish(_payload: bytes) -> None:
        n["k"] += 1
        if n["k"] == 10:
            if how == "stop":
                stop.set()
            elif how == "interrupt":
                raise KeyboardInterrupt
        if how == "publish-error":
            raise OSError("network down")

    with ValveController(path) as vc:
        if how == "interrupt":
            with pytest.raises(KeyboardInterrupt):
                play(vc, cmd_t, duty, publish=publish, out_dir=tmp_path, stop=stop)
        else:
            res = play(vc, cmd_t, duty, publish=publish, out_dir=tmp_path, stop=stop)
            if how == "publish-error":  # counted, never allowed to stop the run
                assert res.status == "success" and res.publish_errors == n["k"]
            else:
                assert res.status == "aborted"
    assert not any(emu.duties) and emu.log[-1].cause == "command"
    meta = json.loads((tmp_path / "run.json").read_text())
    assert meta["valves_closed_confirmed"] is True
    df = pd.read_csv(tmp_path / "commands.csv")
    assert not df.iloc[-1, 1:].any()
    if how != "publish-error":
        assert meta["status"] == "aborted" and len(df) < len(cmd_t)


def test_play_cli_refuses_bad_options_in_one_line(tpods_exe, tmp_path):
    from tests.support.cli import run_in_process

    for extra, msg in ((["--time-scale", "3"], "--clock-origin"),
                       (["--duty-limits", "90,10"], "--duty-limits"),
                       (["--input", str(tmp_path / "nope.csv")], "unknown input")):
        r = run_in_process("run", "play", "--valves", "/dev/null/none", *extra)
        assert r.returncode == 2 and msg in r.stderr and len(r.stderr.strip().splitlines()) == 1, \
            r.stderr


def test_play_waits_for_a_subscriber_of_its_commands(valves, tmp_path):
    """``run play --wait-subscriber S`` (the demo starts the player beside the estimator): no
    valve opens and no command goes out before a subscriber of the command key exists, and
    that subscriber receives every command, from the first (seq 1) to the end."""
    from common.zenoh_net import open_session
    from tests.support.cli import run_in_process
    from tests.support.net import free_port

    emu, path = valves
    ep = f"tcp/127.0.0.1:{free_port()}"
    hub = open_session(listen=[ep], no_multicast=True)
    got: list[bytes] = []
    t_sub: list[float] = []
    subs = []

    def subscribe_late():
        time.sleep(0.8)
        subs.append(hub.declare_subscriber("tpods/tpods1/cmd",
                                           lambda s: got.append(bytes(s.payload.to_bytes()))))
        t_sub.append(time.monotonic())

    th = threading.Thread(target=subscribe_late, daemon=True)
    try:
        th.start()
        r = run_in_process("run", "play", "--valves", path, "--input", "phase-sine",
                           "--duration", "1", "--out", str(tmp_path / "p"), "--no-progress",
                           "--wait-subscriber", "20", "--connect", ep, "--no-multicast")
        th.join(5)
        time.sleep(0.2)  # the last messages in flight on loopback
        assert r.returncode == 0, r.stderr
        assert "no subscriber" not in r.stderr
        first_open = next(c.t for c in emu.log if any(c.duties))
        assert first_open > t_sub[0] - 0.05  # 50 ms: the declaration's trip to the player
        dec = _decode_all(got)
        n_cmd = len(pd.read_csv(tmp_path / "p" / "commands.csv"))
        assert [m["seq"] for m in dec] == list(range(1, len(dec) + 1))
        assert len([m for m in dec if m["kind"] != "hold"]) == n_cmd and dec[-1]["kind"] == "end"
        # nobody listening: a warning after S seconds, and the run is played
        r = run_in_process("run", "play", "--valves", path, "--input", "phase-sine",
                           "--duration", "0.5", "--no-progress", "--wait-subscriber", "0.3",
                           "--connect", ep, "--no-multicast", "--prefix", "nobody")
        assert r.returncode == 0, r.stderr
        assert "play: warning: no subscriber of nobody/tpods1/cmd after 0.3 s" in r.stderr
    finally:
        for s in subs:
            s.undeclare()
        hub.close()
