"""The plant in the loop follows the emulated valves exactly; the CLIs refuse bad input in one line."""

from __future__ import annotations

import math
import socket
import subprocess
import time

import numpy as np
import pandas as pd

from bench.emulators import EmulatedValveController
from common.thrust_table import ThrustTable
from estimator.plant.model import PlantParams, integrate_zoh
from mocap_bridge.sources.vicon_udp import parse_datagram
from tests.support.cli import run_in_process
from tests.support.net import free_port
from tpods.clock import LabClock
from tpods.plant_loop import MocapNoise, PlantLoop


def test_plant_integrates_the_model_exactly_under_the_valve_switches():
    valves = EmulatedValveController(4)
    table = ThrustTable.default()
    params = PlantParams(1.9, 3.1e-3, ct=0.05)
    got: list[tuple] = []
    plant = PlantLoop(valves, params, table, lambda *a: got.append(a),
                      clock=LabClock(10.0, time.time()), pose_rate_hz=100.0,
                      noise=MocapNoise(0.0, 0.0, 0.0))
    with plant:
        for duties in ("60 0 60 0", "0 40 0 40", "30 30 70 70", "0 0 0 0"):
            time.sleep(0.04)
            valves.process_line(f"DUTY* {duties}")
        time.sleep(0.05)
    t, states = plant.truth_arrays()
    assert len(t) > 50 and len(plant.switches) == 4
    sw_t = np.array([s[0] for s in plant.switches])
    thrust = table.thrust_n(np.array([s[1] for s in plant.switches]), clamp=True)
    ref = integrate_zoh(np.zeros(6), np.r_[t[0], sw_t], np.vstack([np.zeros(4), thrust]), t, params)
    assert np.max(np.abs(states - ref)) < 1e-9
    assert abs(states[-1, 5]) > 0.05 and abs(states[-1, 1]) > 1e-3  # it did turn and move
    # noise-free poses are the truth, frames count up, yaw wrapped
    frames = [g[0] for g in got]
    assert frames == list(range(1, len(got) + 1))
    assert np.allclose([g[2] for g in got], states[:len(got), 0])
    assert all(-math.pi <= g[4] <= math.pi for g in got)


def test_plant_command_streams_tracker_udp(tpods_exe, tmp_path):
    port = free_port(socket.SOCK_DGRAM)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", port))
    sock.settimeout(20)
    p = subprocess.Popen([tpods_exe, "run", "plant", "--mocap", f"udp:127.0.0.1:{port}",
                          "--duration", "1.5", "--body", "mod1", "--occlusion", "0.2",
                          "--truth-out", str(tmp_path)], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True)
    try:
        frames = []
        for _ in range(60):
            frame, items = parse_datagram(sock.recv(2048))
            frames.append(frame)
            assert items[0][1] == "mod1"
        out, err = p.communicate(timeout=30)
    finally:
        if p.poll() is None:
            p.kill()
        sock.close()
    assert p.returncode == 0, err
    assert out.startswith("valves: /dev/pts/")
    assert frames == sorted(frames)
    truth = pd.read_csv(tmp_path / "truth.csv")
    assert len(truth) >= 150 and (truth[["x", "y", "u"]] == 0).all().all()  # valves never opened


def test_live_cli_refuses_bad_input_in_one_line(tpods_exe, tmp_path):
    for extra, msg in ((["--thrust-table", str(tmp_path / "no.toml")], "no.toml"),
                       (["--method", "ls-ekf", "--ls-window", "-1"], "ls-window"),
                       (["--zenoh-config", str(tmp_path / "z.json5")], "zenoh config")):
        r = run_in_process("estimate", "live", *extra)
        assert r.returncode == 2 and msg in r.stderr and len(r.stderr.strip().splitlines()) == 1, \
            r.stderr
