"""Zenoh streams in MCAP (issue 19): the writer, export of a run folder, `mocap record
--mcap`, `estimate live --mcap`, `tpods replay`, and a SIGKILL during a recording.

Files are checked with the `mcap` library's own readers: the seeking reader (summary,
statistics, chunk indexes; chunk CRCs), the non-seeking reader with CRC validation (chunk
and data-section CRCs), every message, channel and schema read back.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import NonSeekingReader, make_reader

from common.mcap.log import (
    MESSAGE_ENCODING,
    RAW_ENCODING,
    SCHEMA_ENCODING,
    McapLog,
    has_summary,
    read_mcap,
)
from common.runfolder import read_table
from common.wire import cmd_key, encode_command, encode_pose, pose_key
from common.wire_schemas import SCHEMAS
from common.zenoh_net import open_session
from tests.support.net import Collector, free_port, matching, wait_for
from tpods.cli import main


def check_valid(path: Path) -> dict:
    """The mcap library's checks on a complete file; returns {topic: [payload, ...]}."""
    with open(path, "rb") as f:
        r = make_reader(f, validate_crcs=True)
        summary = r.get_summary()
        assert summary is not None and summary.statistics is not None
        msgs = list(r.iter_messages())
        assert len(msgs) == summary.statistics.message_count
        for sch in summary.schemas.values():
            assert sch.encoding == SCHEMA_ENCODING and json.loads(sch.data) == SCHEMAS[sch.name]
        for ch in summary.channels.values():
            assert ch.message_encoding in (MESSAGE_ENCODING, RAW_ENCODING)
        assert sum(summary.statistics.channel_message_counts.values()) == len(msgs)
        names = [m.name for m in r.iter_metadata()]
        assert names[0] == "tpods" and names[-1] == "tpods.end"
    with open(path, "rb") as f:  # validates chunk CRCs and the data section CRC
        again = list(NonSeekingReader(f, validate_crcs=True).iter_messages(log_time_order=False))
    assert len(again) == len(msgs)
    out: dict = {}
    for _s, ch, m in msgs:
        out.setdefault(ch.topic, []).append(bytes(m.data))
    return out


def test_log_channels_schemas_times(tmp_path):
    path = tmp_path / "x.mcap"
    with McapLog(path, meta={"key": "tpods/**"}) as log:
        log.write("tpods/mocap/b/pose", encode_pose("b", 1, 12.5, 12.6, (1, 2, 0, 0, 0, 0, 1, 0)), 20_000)
        log.write("tpods/mocap/b/pose", encode_pose("b", 2, 12.6, 12.7, None), 21_000)
        log.write("tpods/b/cmd", encode_command("b", 3, 7.25, [50, 0, 0, 0]), 22_000)
        log.write("tpods/b/estimate", b'{"schema":"tpods.estimate/1","body":"b","t":1.0,"t_pub":2.5,'
                                      b'"phase":"ekf","mass_kg":1,"mass_sigma_kg":0.1,"izz_kgm2":1,'
                                      b'"izz_sigma_kgm2":0.1}', 23_000)
        log.write("tpods/mocap/stats", b'{"schema":"tpods.mocap-stats/1","t":3.0}', 24_000)
        log.write("tpods/b/cmd", b"not json", 25_000)
    by_topic = check_valid(path)
    assert sorted(by_topic) == ["tpods/b/cmd", "tpods/b/estimate", "tpods/mocap/b/pose", "tpods/mocap/stats"]
    r = read_mcap(path)
    assert r.complete and [m.log_time for m in r.messages] == [20_000, 21_000, 22_000, 23_000, 24_000, 25_000]
    # publish_time: the message's own time (pose t, command t, estimate t_pub), else receive time
    assert [m.publish_time for m in r.messages] == [12_500_000_000, 12_600_000_000, 7_250_000_000,
                                                    2_500_000_000, 3_000_000_000, 25_000]
    assert [m.schema for m in r.messages] == ["tpods.pose/1", "tpods.pose/1", "tpods.cmd/1",
                                              "tpods.estimate/1", "tpods.mocap-stats/1", ""]
    assert r.messages[-1].encoding == RAW_ENCODING and r.messages[-1].data == b"not json"
    with open(path, "rb") as f:
        summ = make_reader(f).get_summary()
    assert len(summ.channels) == 5 and len(summ.schemas) == 4  # the raw channel shares its key


def test_payloads_match_their_json_schemas():
    jsonschema = pytest.importorskip("jsonschema")
    for s in SCHEMAS.values():
        jsonschema.Draft202012Validator.check_schema(s)
    jsonschema.validate(json.loads(encode_pose("b", 1, 1.0, 1.0, (1, 2, 0, 0, 0, 0, 1, 0))), SCHEMAS["tpods.pose/1"])
    jsonschema.validate(json.loads(encode_pose("b", 1, 1.0, 1.0, None)), SCHEMAS["tpods.pose/1"])
    jsonschema.validate(json.loads(encode_command("b", 1, 1.0, [1, 2, 3, 4])), SCHEMAS["tpods.cmd/1"])


# ---- export of a run folder


@pytest.fixture(scope="module")
def sim_run(tmp_path_factory) -> Path:
    run = tmp_path_factory.mktemp("sim") / "sim-1"
    assert main(["sim", "--duration", "3", "--drop", "0.05", "--seed", "3", "--out", str(run)]) == 0
    return run


def test_export_of_a_simulated_run_round_trips_every_row(sim_run, tmp_path, capsys):
    out = tmp_path / "sim.mcap"
    assert main(["export", "mcap", str(sim_run), "--out", str(out), "--body", "tpods1"]) == 0
    assert f"wrote {out}" in capsys.readouterr().out
    by_topic = check_valid(out)
    assert sorted(by_topic) == ["tpods/mocap/tpods1/pose", "tpods/tpods1/cmd", "tpods/tpods1/truth"]
    poses = read_table(sim_run / "poses.csv", ("t", "x", "y", "psi"))
    got = [json.loads(p) for p in by_topic["tpods/mocap/tpods1/pose"]]
    assert len(got) == len(poses)
    for row, d in zip(poses, got, strict=True):
        assert (d["t_src"], d["t"], d["x"], d["y"]) == (row[0], row[0], row[1], row[2])
        assert math.remainder(d["yaw"] - row[3], 2 * math.pi) == pytest.approx(0, abs=1e-12)
        assert -math.pi < d["yaw"] <= math.pi and d["qz"] == pytest.approx(math.sin(d["yaw"] / 2))
    cmds = read_table(sim_run / "commands.csv", ("t", "d1", "d2", "d3", "d4"))
    got = [json.loads(p) for p in by_topic["tpods/tpods1/cmd"]]
    assert [[d["t"], *d["duty"]] for d in got] == cmds.tolist()
    assert [d["seq"] for d in got] == list(range(len(cmds)))
    truth = read_table(sim_run / "truth.csv", ("t", "x", "y", "psi", "u", "v", "r"))
    got = [json.loads(p) for p in by_topic["tpods/tpods1/truth"]]
    assert [[d[k] for k in ("t", "x", "y", "psi", "u", "v", "r")] for d in got] == truth.tolist()
    times = [m.log_time for m in read_mcap(out).messages]
    assert times == sorted(times)
    # refused: an existing file without --force, a name that is not .mcap
    assert main(["export", "mcap", str(sim_run), "--out", str(out)]) == 2
    assert "already exists; add --force" in capsys.readouterr().err
    assert main(["export", "mcap", str(sim_run), "--out", str(out), "--force"]) == 0
    assert main(["export", "mcap", str(sim_run), "--out", str(tmp_path / "x")]) == 2
    assert "writes one MCAP file" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sim.mcap"]


def test_export_carries_estimates_csv(sim_run, tmp_path):
    import shutil

    from estimator.live.recorder import ESTIMATE_COLUMNS

    run = tmp_path / "live"
    shutil.copytree(sim_run, run)
    (run / "truth.csv").unlink()
    rows = [[0.5 + 0.1 * i, i, "ekf", 2.2 + i, 0.1, 3.7e-3, 1e-4, *range(6), *[0.01] * 6, 0.09, 0.04,
             9e-5, 4e-5] for i in range(5)]
    (run / "estimates.csv").write_text(",".join(ESTIMATE_COLUMNS) + "\n"
                                       + "".join(",".join(map(str, r)) + "\n" for r in rows))
    out = tmp_path / "live.mcap"
    assert main(["export", "mcap", str(run), "--out", str(out)]) == 0
    by_topic = check_valid(out)
    est = [json.loads(p) for p in by_topic["tpods/live/estimate"]]
    assert [(d["t"], d["frame"], d["phase"], d["mass_kg"], d["state"]["psi"], d["state_sigma"]["r"])
            for d in est] == [(r[0], r[1], "ekf", r[3], 2, 0.01) for r in rows]
    assert "t_pub" not in est[0] and "diverged" not in est[0]  # not in the CSV: left out


# ---- recording from Zenoh


def _publish_poses(session, key, n, rate_hz, stop=None, frames=None):
    pub = session.declare_publisher(key)
    sent = []
    t_next = time.monotonic()
    for i in range(n):
        if stop is not None and stop.is_set():
            break
        t = time.time()
        p = encode_pose("b1", i, t - 0.003, t, (0.001 * i, -0.002 * i, 0, 0, 0, 0, 1, 0.001 * i))
        pub.put(p)
        sent.append((t, p))
        if frames is not None:
            frames.append((i, time.time()))
        t_next += 1.0 / rate_hz
        time.sleep(max(0.0, t_next - time.monotonic()))
    pub.undeclare()
    return sent


def _wait_recorder(session, key="tpods/mocap/probe/pose"):
    probe = session.declare_publisher(key)
    assert wait_for(lambda: matching(probe), 20.0), "recorder never subscribed"
    probe.undeclare()


def test_mocap_record_mcap_holds_the_poses_of_poses_csv(zenoh_pair, tmp_path, capsys):
    pub, _sub, ep = zenoh_pair
    out = tmp_path / "rec"
    res = {}
    th = threading.Thread(target=lambda: res.setdefault("rc", main(
        ["mocap", "record", "--out", str(out), "--mcap", "--connect", ep, "--no-multicast",
         "--duration", "2.5", "--quiet"])))
    th.start()
    _wait_recorder(pub)
    sent = _publish_poses(pub, pose_key("tpods/mocap", "b1"), 200, 200)
    pub.put("tpods/mocap/stats", b'{"schema":"tpods.mocap-stats/1","t":1.0}')
    pub.put("tpods/mocap/b1/pose", b"{broken")
    th.join(20)
    assert res["rc"] == 0
    by_topic = check_valid(out / "recording.mcap")
    assert by_topic["tpods/mocap/b1/pose"][:200] == [p for _t, p in sent]  # bytes, in order
    assert by_topic["tpods/mocap/b1/pose"][200:] == [b"{broken"]
    assert by_topic["tpods/mocap/stats"] == [b'{"schema":"tpods.mocap-stats/1","t":1.0}']
    # the same poses as poses.csv (12 significant digits there)
    rec = json.loads((out / "recording.json").read_text())
    csv = read_table(out / "b1" / "poses.csv", ("t", "x", "y", "psi"))
    got = np.array([[d["t"] - rec["t0_host_s"], d["x"], d["y"], d["yaw"]]
                    for d in map(json.loads, by_topic["tpods/mocap/b1/pose"][:200])])
    assert csv.shape == got.shape == (200, 4)
    np.testing.assert_allclose(csv, got, rtol=1e-11, atol=1e-12)
    # log_time is the receive time: after the send, within a second
    msgs = [m for m in read_mcap(out / "recording.mcap").messages if m.topic.endswith("b1/pose")][:200]
    lag = np.array([m.log_time * 1e-9 - t for m, (t, _p) in zip(msgs, sent, strict=True)])
    assert lag.min() >= -1e-3 and lag.max() < 1.0
    assert "messages on 2 keys written to" in capsys.readouterr().out


def test_mocap_record_out_mcap_writes_just_that_file(zenoh_pair, tmp_path):
    pub, _sub, ep = zenoh_pair
    out = tmp_path / "rec.mcap"
    res = {}
    th = threading.Thread(target=lambda: res.setdefault("rc", main(
        ["mocap", "record", "--out", str(out), "--connect", ep, "--no-multicast",
         "--duration", "1.5", "--quiet"])))
    th.start()
    _wait_recorder(pub)
    sent = _publish_poses(pub, pose_key("tpods/mocap", "b1"), 50, 200)
    th.join(20)
    assert res["rc"] == 0 and sorted(p.name for p in tmp_path.iterdir()) == ["rec.mcap"]
    assert check_valid(out)["tpods/mocap/b1/pose"] == [p for _t, p in sent]
    assert main(["mocap", "record", "--out", str(out), "--duration", "1"]) == 2  # exists: --force


# ---- replay


def test_replay_publishes_the_same_payloads_in_order(sim_run, zenoh_pair, tmp_path, capsys):
    f = tmp_path / "sim.mcap"
    assert main(["export", "mcap", str(sim_run), "--out", str(f), "--body", "tpods1"]) == 0
    want = [(m.topic, m.data) for m in read_mcap(f).messages]
    listener, _other, ep = zenoh_pair
    got = Collector()
    s = listener.declare_subscriber("**", got)
    t0 = time.monotonic()
    assert main(["replay", str(f), "--speed", "4", "--connect", ep, "--no-multicast",
                 "--wait-subscriber", "10", "--quiet"]) == 0
    elapsed = time.monotonic() - t0
    assert wait_for(lambda: len(got) >= len(want), 5.0)
    s.undeclare()
    assert got.items == want
    assert "messages on 3 keys, 3.000 s of recording" in capsys.readouterr().out
    assert 0.7 < elapsed < 4.0  # 3 s at speed 4 (0.75 s) plus a session's start
    # --prefix OLD=NEW remaps the keys, as fast as possible with --speed 0
    got2 = Collector()
    s = listener.declare_subscriber("lab2/**", got2)
    assert main(["replay", str(f), "--speed", "0", "--prefix", "tpods=lab2", "--connect", ep,
                 "--no-multicast", "--wait-subscriber", "10", "--quiet"]) == 0
    assert wait_for(lambda: len(got2) >= len(want), 5.0)
    s.undeclare()
    assert got2.items == [("lab2/" + k.removeprefix("tpods/"), p) for k, p in want]


def test_replay_refuses_what_is_not_mcap(tmp_path, capsys):
    bad = tmp_path / "x.mcap"
    bad.write_text("hello\n")
    assert main(["replay", str(bad)]) == 2
    assert capsys.readouterr().err == f"tpods: error: {bad}: not an MCAP file\n"


# ---- the live estimator


def test_estimate_live_records_its_streams(sim_run, tmp_path, tpods_exe):
    """An exported run replayed into `tpods estimate live --mcap` (a subprocess): its
    recording.mcap holds the poses and commands it received and the estimates it published."""
    f = tmp_path / "sim.mcap"
    assert main(["export", "mcap", str(sim_run), "--out", str(f), "--body", "tpods1"]) == 0
    ep = f"tcp/127.0.0.1:{free_port()}"
    out = tmp_path / "live"
    live = subprocess.Popen([tpods_exe, "estimate", "live", "--body", "tpods1", "--out", str(out),
                             "--mcap", "--listen", ep, "--no-multicast", "--rate", "0",
                             "--exit-on-end", "--duration", "60", "--quiet"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        session = open_session(connect=[ep], no_multicast=True)
        try:
            probe = session.declare_publisher(cmd_key("tpods1"))
            assert wait_for(lambda: matching(probe), 30.0), "live estimator never subscribed"
            probe.undeclare()
            from common.mcap.replay import replay

            replay(session, f, speed=4)
        finally:
            session.close()
        so, se = live.communicate(timeout=60)
    finally:
        if live.poll() is None:
            live.kill()
    assert live.returncode == 0, se
    by_topic = check_valid(out / "recording.mcap")
    sent = {m.topic: [] for m in read_mcap(f).messages}
    for m in read_mcap(f).messages:
        sent[m.topic].append(m.data)
    assert by_topic["tpods/mocap/tpods1/pose"] == sent["tpods/mocap/tpods1/pose"]
    assert by_topic["tpods/tpods1/cmd"] == sent["tpods/tpods1/cmd"]
    est = [json.loads(p) for p in by_topic["tpods/tpods1/estimate"]]
    n_est = len(read_table(out / "estimates.csv", ("t", "mass_kg")))
    # one per update (--rate 0), and the last one again when the run ends
    assert n_est > 100 and n_est <= len(est) <= n_est + 2
    assert all(d["schema"] == "tpods.estimate/1" for d in est)
    final = json.loads((out / "estimate.json").read_text())
    assert est[-1]["mass_kg"] == pytest.approx(final["mass_kg"], rel=1e-9)


# ---- a kill


@pytest.mark.parametrize("out_name", ["rec.mcap", "rec"])
def test_sigkill_loses_at_most_a_tenth_of_a_second(out_name, tmp_path, tpods_exe):
    ep = f"tcp/127.0.0.1:{free_port()}"
    out = tmp_path / out_name
    argv = [tpods_exe, "mocap", "record", "--out", str(out), "--listen", ep, "--no-multicast", "--quiet"]
    rec = subprocess.Popen(argv + ([] if out_name.endswith(".mcap") else ["--mcap"]),
                           stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    session = open_session(connect=[ep], no_multicast=True)
    stop = threading.Event()
    frames: list[tuple[int, float]] = []
    try:
        _wait_recorder(session)
        th = threading.Thread(target=_publish_poses,
                              args=(session, pose_key("tpods/mocap", "b1"), 100_000, 500, stop, frames))
        th.start()
        time.sleep(2.0)
        t_kill = time.time()
        os.kill(rec.pid, signal.SIGKILL)
        rec.wait(10)
        stop.set()
        th.join(10)
    finally:
        session.close()
        if rec.poll() is None:
            rec.kill()
    path = out if out_name.endswith(".mcap") else out / "recording.mcap"
    assert not has_summary(path)  # cut: no summary, no footer; the seeking reader gives up
    with open(path, "rb") as f, pytest.raises(Exception):  # noqa: B017 (whatever it raises)
        list(make_reader(f).iter_messages())
    r = read_mcap(path)  # the recovery: every complete chunk, linearly
    assert not r.complete
    got = [json.loads(m.data)["frame"] for m in r.messages]
    assert got == list(range(len(got)))  # nothing lost before the cut, in order
    sent_before = [i for i, t in frames if t <= t_kill - 0.1]
    assert len(got) >= len(sent_before), (len(got), len(sent_before))
    lost_s = t_kill - r.messages[-1].log_time * 1e-9
    assert lost_s <= 0.1, lost_s
    print(f"SIGKILL: {len(got)} messages recovered, last received {lost_s * 1e3:.1f} ms before the kill")
