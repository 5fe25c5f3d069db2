"""Replay, simulation and push sources; the recorder; record-then-replay round trip.

"Unchanged" means: every line of the recorded ``<body>/poses.csv`` has the same text as
the original ``poses.csv`` written by ``common.runfolder.write_run`` (12 significant
digits) for t, x and y, and for psi whenever the written psi lies inside (-pi, pi]; a
psi outside (unwrapped, or pi rounded up to 3.14159265359 by the 12-digit format) comes
back as the same angle wrapped to (-pi, pi] (the payload carries wrapped yaw; the
run-folder contract treats both as the same yaw).
"""

from __future__ import annotations

import json
import math
import threading
import time

import numpy as np
import pytest

from common.errors import UserError
from common.runfolder import write_run
from estimator.plant.inputs import phase_sine
from estimator.plant.model import PlantParams, wrap_angle
from estimator.plant.sim import SimConfig, simulate, write_sim_run
from mocap_bridge.bridge import Bridge
from mocap_bridge.pose import decode_pose, encode_pose, yaw_quat
from mocap_bridge.recorder import Recorder, subscribe
from mocap_bridge.sources.push import PushSource
from mocap_bridge.sources.replay import ReplaySource
from tests.support.net import RunningBridge, matching, wait_for
from tpods.sim_source import SimSource


def _odd_run(path, n=400, seed=5):
    """A run folder with irregular times (dropped frames), wrapped yaw near +-pi."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 120.0
    keep = rng.random(n) > 0.1
    keep[0] = True
    t = t[keep]
    psi = wrap_angle(np.linspace(-3.5, 9.0, len(t)) + rng.normal(0, 1e-3, len(t)))
    psi[5] = math.pi
    pose = np.column_stack([rng.normal(0, 0.3, len(t)), rng.normal(0, 0.3, len(t)), psi])
    pose[7, :2] = [1e-9, -123.456789012345]
    return write_run(path, cmd_t=np.array([0.0, t[-1] + 0.01]), duty_pct=np.zeros((2, 4)),
                     pose_t=t, pose=pose)


def assert_unchanged(orig_file, rec_file):
    a = orig_file.read_text().splitlines()
    b = rec_file.read_text().splitlines()
    assert len(a) == len(b) and a[0] == b[0]
    n_wrapped = 0
    for la, lb in zip(a[1:], b[1:], strict=True):
        ta, tb = la.split(","), lb.split(",")
        assert ta[:3] == tb[:3]
        psi = float(ta[3])
        if -math.pi < psi <= math.pi:
            assert ta[3] == tb[3]
        else:
            n_wrapped += 1
            assert float(tb[3]) == pytest.approx(float(wrap_angle(psi)), abs=1e-11)
    return n_wrapped


def _record_replay(pub_s, sub_s, src, out):
    rec = Recorder(out, key="tpods/mocap/**")
    sub = subscribe(sub_s, "tpods/mocap/**", rec)
    probe = pub_s.declare_publisher("tpods/mocap/x/pose")
    assert wait_for(lambda: matching(probe), 10.0)
    probe.undeclare()
    n = sum(len(f.poses) for f in src.frames)
    bridge = Bridge(pub_s)
    bridge.run(src)
    assert wait_for(lambda: rec.counters["received"] - rec.counters.get("other_schema", 0) >= n, 20.0)
    sub.undeclare()
    rec.close()
    return rec, bridge


def test_record_then_replay_round_trips_a_run_folder(zenoh_pair, tmp_path):
    pub_s, sub_s, _ = zenoh_pair
    orig = _odd_run(tmp_path / "orig")
    src = ReplaySource(orig, rate_scale=0.0, body="mod1")
    rec, bridge = _record_replay(pub_s, sub_s, src, tmp_path / "rec")
    assert assert_unchanged(orig / "poses.csv", tmp_path / "rec" / "mod1" / "poses.csv") == 1
    assert rec.counters["malformed"] == 0 and rec.counters["not_increasing"] == 0
    # frame numbers came from the times: the dropped frames are counted as gaps
    n_rows = len((orig / "poses.csv").read_text().splitlines()) - 1
    assert bridge.stats.bodies["mod1"].gaps == round(orig_t_last(orig) * 120) + 1 - n_rows
    # replaying the recording (samples.csv, a bridge log) round-trips again
    src2 = ReplaySource(tmp_path / "rec", rate_scale=0.0)
    _record_replay(pub_s, sub_s, src2, tmp_path / "rec2")
    assert assert_unchanged(orig / "poses.csv", tmp_path / "rec2" / "mod1" / "poses.csv") == 1
    # a run that tpods sim wrote (yaw inside (-pi, pi]) comes back byte-identical
    cmd_t, duty = phase_sine(2.0, 50.0)
    res = simulate(cmd_t, duty, PlantParams(2.0, 3e-3), config=SimConfig(seed=2, drop=0.05))
    sim = write_sim_run(res, tmp_path / "sim")
    _record_replay(pub_s, sub_s, ReplaySource(sim, rate_scale=0.0), tmp_path / "rec3")
    assert (tmp_path / "rec3" / "sim" / "poses.csv").read_text() == (sim / "poses.csv").read_text()


def orig_t_last(path):
    return float((path / "poses.csv").read_text().splitlines()[-1].split(",")[0])


def test_paced_replay_uses_the_host_clock_at_the_rate_scale(tmp_path):
    orig = _odd_run(tmp_path / "orig", n=60)
    src = ReplaySource(orig, rate_scale=20.0)
    t0 = time.monotonic()
    batches = list(src.batches(threading.Event()))
    elapsed = time.monotonic() - t0
    samples = [s for b in batches for s in b]
    t_src = np.array([s.t_src for s in samples])
    t = np.array([s.t for s in samples])
    assert np.allclose(t - t[0], (t_src - t_src[0]) / 20.0, atol=1e-6)
    assert elapsed >= (t_src[-1] - t_src[0]) / 20.0 - 1e-3  # never early
    assert all(s.t_recv >= s.t - 1e-3 for s in samples)
    stop = threading.Event()
    stop.set()
    assert list(ReplaySource(orig, rate_scale=1.0).batches(stop)) == []


def test_sim_source_reproduces_a_simulated_run(tmp_path):
    cmd_t, duty = phase_sine(3.0, 50.0)
    res = simulate(cmd_t, duty, PlantParams(1.5, 2e-3),
                   config=SimConfig(seed=11, drop=0.1, pose_rate_hz=100.0))
    run = write_sim_run(res, tmp_path / "sim", "phase-sine")
    src = SimSource.from_run(run, rate_scale=0.0, body="m")
    t = np.array([f.t_src for f in src.frames])
    xyz = np.array([f.poses[0][1:3] for f in src.frames])
    yaw = np.array([2 * math.atan2(f.poses[0][6], f.poses[0][7]) for f in src.frames])
    assert np.array_equal(t, res.pose_t) and np.allclose(xyz, res.pose[:, :2], atol=1e-9, rtol=0)
    assert np.allclose(wrap_angle(yaw - res.pose[:, 2]), 0, atol=1e-12)
    frames = np.array([f.frame for f in src.frames])
    assert np.array_equal(frames, np.rint(res.pose_t * 100).astype(int) + 1)
    with pytest.raises(UserError, match="truth"):
        (tmp_path / "sim" / "run.json").write_text("{}")
        SimSource.from_run(run)


def test_push_source_feeds_a_live_producer_through_the_bridge(zenoh_pair, tmp_path):
    pub_s, sub_s, _ = zenoh_pair
    rec = Recorder(tmp_path / "live")
    sub = subscribe(sub_s, "tpods/mocap/**", rec)
    probe = pub_s.declare_publisher("tpods/mocap/x/pose")
    assert wait_for(lambda: matching(probe), 10.0)
    probe.undeclare()
    push = PushSource("plant", maxsize=50)
    t0 = time.time()

    def producer():
        for k in range(300):
            psi = 0.02 * k
            push.push_planar("a", t0 + k / 1000, 0.001 * k, -0.001 * k, psi)
            if k % 10 == 0:
                push.push_pose("b", k, t0 + k / 1000, 1.0, 2.0, 3.0, (math.nan,) * 4, occluded=True)
        push.finish()

    th = threading.Thread(target=producer)
    with RunningBridge(Bridge(pub_s), push):
        th.start()
        th.join(10.0)
        assert wait_for(lambda: rec.counters["received"] - rec.counters.get("other_schema", 0) >= 330,
                        10.0)
    sub.undeclare()
    rec.close()
    assert rec.counters["recorded"] == 300 and rec.counters["occluded"] == 30
    pv = np.loadtxt(tmp_path / "live" / "a" / "poses.csv", delimiter=",", skiprows=1)
    assert np.allclose(pv[:, 0], np.arange(300) / 1000, atol=1e-6)  # t - t0 of the first sample
    assert np.allclose(pv[:, 3], wrap_angle(0.02 * np.arange(300)), atol=1e-12)
    b_poses = (tmp_path / "live" / "b" / "poses.csv").read_text().splitlines()
    b_samples = (tmp_path / "live" / "b" / "samples.csv").read_text().splitlines()
    assert b_poses == ["t,x,y,psi"] and len(b_samples) == 31
    assert all(line.endswith(",true," + line.rsplit(",", 1)[1]) for line in b_samples[1:])
    meta = json.loads((tmp_path / "live" / "recording.json").read_text())
    assert meta["bodies"] == {"a": "a", "b": "b"} and meta["counters"]["recorded"] == 300


def test_recorder_flushes_each_sample_and_counts_bad_payloads(tmp_path):
    rec = Recorder(tmp_path / "r")
    q = yaw_quat(0.5)
    rec.handle(encode_pose("m/1", 1, 1000.0, 1000.0, (0.1, 0.2, 0.0, *q, 0.5)))
    # readable before close: a crash now loses nothing already received
    assert (tmp_path / "r" / "m_1" / "poses.csv").read_text() == "t,x,y,psi\n0,0.1,0.2,0.5\n"
    assert len((tmp_path / "r" / "m_1" / "samples.csv").read_text().splitlines()) == 2
    rec.handle(b"garbage")
    rec.handle(b'{"schema":"tpods.mocap-stats/1"}')
    rec.handle(encode_pose("m/1", 2, 999.0, 1000.0, (0.1, 0.2, 0.0, *q, 0.5)))  # goes back in time
    rec.handle(encode_pose("m 1", 3, 1001.0, 1001.0, (0.3, 0.2, 0.0, *q, 0.5)))  # same sanitised name
    c = rec.close()
    assert c["malformed"] == 1 and c["other_schema"] == 1 and c["not_increasing"] == 1
    assert c["recorded"] == 2
    assert rec.bodies == {"m/1": "m_1", "m 1": "m_1_"}
    assert decode_pose(b"garbage") is None


def test_replay_refuses_bad_folders_with_one_line(tmp_path):
    with pytest.raises(UserError, match="not found"):
        ReplaySource(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(UserError, match="neither"):
        ReplaySource(tmp_path / "empty")
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "poses.csv").write_text("t,x,y,psi\n0,0,0,0\n0.1,nan,0,0\n")
    with pytest.raises(UserError, match="line 3"):
        ReplaySource(bad)


def test_recorder_subscriber_counts_write_errors(tmp_path):
    rec = Recorder(tmp_path / "r")

    class FakeSession:
        def declare_subscriber(self, key, cb):
            self.cb = cb
            return self

    class FakeSample:
        class payload:  # noqa: N801 - mimics zenoh's attribute
            @staticmethod
            def to_bytes():
                return encode_pose("m", 1, 1.0, 1.0, (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0))

    fs = FakeSession()
    subscribe(fs, "tpods/mocap/**", rec)
    orig = rec.handle

    def failing(payload, t_rx=None):  # the way a full disk fails a write
        raise OSError(28, "No space left on device")

    rec.handle = failing
    fs.cb(FakeSample())
    assert rec.counters["write_errors"] == 1 and "No space" in rec.last_error
    rec.handle = orig
    fs.cb(FakeSample())
    assert rec.close()["recorded"] == 1
