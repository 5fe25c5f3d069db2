"""Killing the player, the bridge or the live estimator mid-run (real subprocesses, SIGKILL
and SIGTERM) leaves the valves closed and the recorded files readable up to the kill.

The lab: an emulated valve controller on a pty and the simulated module in this process
(poses sent as Vicon Tracker UDP datagrams), ``tpods mocap bridge --source vicon-udp``,
``tpods estimate live`` and ``tpods run play`` as subprocesses, Zenoh on loopback.
"""

from __future__ import annotations

import signal
import subprocess
import time
from pathlib import Path

import pandas as pd
import pytest

from bench.emulators import EmulatedValveController, serve_pty
from common.runfolder import read_run
from common.thrust_table import ThrustTable
from tests.support.lab import TRUTH
from tests.support.net import free_port, wait_for
from tpods.plant_loop import PlantLoop, udp_sink

ZARGS = ["--no-multicast"]


def _lines(path: Path) -> int:
    try:
        return max(0, len(path.read_text().splitlines()) - 1)
    except OSError:
        return 0


class Lab:
    def __init__(self, tmp: Path, exe: str) -> None:
        self.tmp = tmp
        self.exe = exe
        self.valves = EmulatedValveController(4)
        self.server = serve_pty(self.valves)
        self.udp_port = free_port(kind=2)  # SOCK_DGRAM
        self.ep = f"tcp/127.0.0.1:{free_port()}"
        self.plant = PlantLoop(self.valves, TRUTH, ThrustTable.default(),
                               udp_sink(("127.0.0.1", self.udp_port)))
        self.procs: dict[str, subprocess.Popen] = {}

    def spawn(self, name: str, args: list[str]) -> subprocess.Popen:
        err = (self.tmp / f"{name}.err").open("w")
        p = subprocess.Popen([self.exe, *args], stdout=subprocess.PIPE, stderr=err, text=True)
        self.procs[name] = p
        return p

    def err(self, name: str) -> str:
        return (self.tmp / f"{name}.err").read_text()

    def start(self, duration_s: float = 12.0) -> None:
        self.plant.start()
        self.spawn("bridge", ["mocap", "bridge", "--source", f"vicon-udp:{self.udp_port}",
                              "--bind", "127.0.0.1", "--listen", self.ep, "--quiet", *ZARGS])
        assert wait_for(lambda: "bridge:" in self.err("bridge"), 30.0), self.err("bridge")
        self.spawn("live", ["estimate", "live", "--body", "tpods1", "--connect", self.ep,
                            "--out", str(self.tmp / "live"), "--quiet", *ZARGS])
        assert wait_for(lambda: "live:" in self.err("live"), 30.0), self.err("live")
        time.sleep(0.5)  # subscriptions propagate
        self.spawn("play", ["run", "play", "--valves", self.server.path, "--input", "phase-sine",
                            "--duration", str(duration_s), "--body", "tpods1", "--connect", self.ep,
                            "--out", str(self.tmp / "play"), "--no-progress", *ZARGS])
        assert wait_for(lambda: _lines(self.tmp / "play" / "commands.csv") > 50, 30.0), \
            self.err("play")
        assert wait_for(lambda: _lines(self.tmp / "live" / "poses.csv") > 100, 15.0), \
            self.err("live") + self.err("bridge")

    def stop(self) -> None:
        for p in self.procs.values():
            if p.poll() is None:
                p.kill()
            p.wait(timeout=10)
        self.plant.stop()
        self.server.stop()


@pytest.fixture
def lab(tmp_path, tpods_exe):
    lab = Lab(tmp_path, tpods_exe)
    try:
        yield lab
    finally:
        lab.stop()


def _play_commands(lab: Lab) -> pd.DataFrame:
    df = pd.read_csv(lab.tmp / "play" / "commands.csv")
    assert list(df.columns) == ["t", "d1", "d2", "d3", "d4"] and len(df) > 50
    assert df["t"].is_monotonic_increasing
    return df


def test_kill_bridge_then_term_estimator_then_kill_player(lab):
    lab.start()
    # the bridge dies: poses stop, the estimator and the player carry on
    lab.procs["bridge"].kill()
    lab.procs["bridge"].wait(10)
    n_before = _lines(lab.tmp / "live" / "poses.csv")
    time.sleep(0.5)
    assert lab.procs["live"].poll() is None and lab.procs["play"].poll() is None
    # SIGTERM the estimator: it stops cleanly and closes its run folder
    lab.procs["live"].send_signal(signal.SIGTERM)
    assert lab.procs["live"].wait(20) == 0, lab.err("live")
    run = read_run(lab.tmp / "live")
    assert run.meta["status"] == "stopped" and len(run.pose_t) >= n_before
    est = pd.read_csv(lab.tmp / "live" / "estimates.csv")
    assert len(est) == len(run.pose_t) and est["mass_kg"].notna().all()
    # SIGKILL the player with the valves open: the controller watchdog closes them
    assert any(lab.valves.duties)
    lab.procs["play"].kill()
    t_kill = time.monotonic()
    lab.procs["play"].wait(10)
    assert wait_for(lambda: not any(lab.valves.duties), 2.0)
    closed = lab.valves.closed_since()
    assert lab.valves.log[-1].cause == "watchdog" and closed - t_kill < 0.5 + 0.1
    df = _play_commands(lab)  # flushed per row: readable up to the kill
    assert (df.iloc[:, 1:] > 0).any(axis=1).iloc[-1]  # no closing row: the player died
    sent = [c for c in lab.valves.log if c.cause == "command"]
    assert len(df) >= len(sent) - 1  # every command the controller got is in the file (but the last)


def test_term_player_then_kill_estimator_then_term_bridge(lab):
    lab.start()
    # SIGTERM the player: its finally closes the valves (OFF + STATE?) and writes the closing row
    lab.procs["play"].send_signal(signal.SIGTERM)
    t_term = time.monotonic()
    assert lab.procs["play"].wait(10) == 143, lab.err("play")
    assert not any(lab.valves.duties) and lab.valves.log[-1].cause == "command"
    assert lab.valves.closed_since() - t_term < 0.2
    df = _play_commands(lab)
    assert not df.iloc[-1, 1:].any()  # the closing all-zero row
    import json
    meta = json.loads((lab.tmp / "play" / "run.json").read_text())
    assert meta["status"] == "aborted" and meta["valves_closed_confirmed"] is True
    time.sleep(0.5)  # the estimator sees the end message and the last poses
    # SIGKILL the estimator: its folder is a valid run up to the kill
    lab.procs["live"].kill()
    lab.procs["live"].wait(10)
    run = read_run(lab.tmp / "live")
    assert run.meta["status"] == "running"  # it never got to close: the host died
    assert len(run.pose_t) > 100 and not run.duty_pct[-1].any()  # the player's end made it in
    # SIGTERM the bridge: clean exit
    lab.procs["bridge"].send_signal(signal.SIGTERM)
    assert lab.procs["bridge"].wait(10) == 0, lab.err("bridge")
