"""`tpods mocap bridge` and `tpods mocap record` as a user runs them (subprocesses;
the one-line user errors in process, with the same exit code and stderr)."""

from __future__ import annotations

import socket
import subprocess

import pytest

from estimator.plant.inputs import phase_sine
from estimator.plant.model import PlantParams
from estimator.plant.sim import SimConfig, simulate, write_sim_run
from mocap_bridge.sources.vicon_udp import build_datagram
from tests.support.cli import run_in_process
from tests.support.net import free_port, wait_for


def _run(exe, *args, timeout=60):
    return subprocess.run([exe, *args], capture_output=True, text=True, timeout=timeout)


def test_bridge_replay_to_recorder_over_loopback(tpods_exe, tmp_path):
    cmd_t, duty = phase_sine(2.0, 50.0)
    res = simulate(cmd_t, duty, PlantParams(2.268, 3.78e-3), config=SimConfig(seed=4, drop=0.05))
    run = write_sim_run(res, tmp_path / "run1")
    n = len(res.pose_t)
    missing = 241 - n  # 2 s at 120 Hz: 241 nominal frames, some dropped
    assert missing > 0
    ep = f"tcp/127.0.0.1:{free_port()}"
    rec = subprocess.Popen([tpods_exe, "mocap", "record", "--out", str(tmp_path / "rec"),
                            "--listen", ep, "--no-multicast", "--duration", "30"],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        br = _run(tpods_exe, "mocap", "bridge", "--source", f"replay:{run}", "--rate-scale", "4",
                  "--connect", ep, "--no-multicast", "--wait-subscriber", "20")
        assert br.returncode == 0, br.stderr
        assert f"published {n} poses of 1 bodies" in br.stdout
        assert f"{missing} missing frames" in br.stdout
        assert "mocap: 1 bodies" in br.stderr  # the console line of live statistics
        poses = tmp_path / "rec" / "run1" / "poses.csv"
        assert wait_for(lambda: poses.exists() and len(poses.read_text().splitlines()) == n + 1, 10.0)
    finally:
        rec.terminate()  # SIGTERM: the recorder closes its files and reports
        out, err = rec.communicate(timeout=20)
    assert rec.returncode == 0, err
    assert f"record: {n} poses of 1 bodies" in out
    assert poses.read_text() == (run / "poses.csv").read_text()


def test_bridge_udp_source_cli_duration(tpods_exe, tmp_path):
    port = free_port(socket.SOCK_DGRAM)
    ep = f"tcp/127.0.0.1:{free_port()}"
    p = subprocess.Popen([tpods_exe, "mocap", "bridge", "--source", f"vicon-udp:{port}",
                          "--bind", "127.0.0.1", "--listen", ep, "--no-multicast",
                          "--duration", "4"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True)

    def bound() -> bool:  # the bridge holds the port once our own bind fails
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            try:
                probe.bind(("127.0.0.1", port))
            except OSError:
                return True
            return False

    assert wait_for(bound, 60.0, 0.05), "the bridge never bound its UDP port"
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    for f in range(1, 6):
        tx.sendto(build_datagram(f, [(0, "m", (1.0, 2.0, 3.0, 0.0, 0.0, 0.1))], 1024), ("127.0.0.1", port))
    tx.sendto(b"junk", ("127.0.0.1", port))
    tx.close()
    out, err = p.communicate(timeout=30)
    assert p.returncode == 0, err
    assert "published 5 poses of 1 bodies" in out and "6 datagrams, 1 malformed" in out


@pytest.mark.parametrize("args, msg", [
    (["bridge", "--source", "bogus"], "unknown source"),
    (["bridge", "--source", "replay:/nonexistent/x"], "replay folder not found"),
    (["bridge", "--source", "vicon-udp:70000"], "bad UDP port"),
    (["bridge", "--source", "sim", "--zenoh-config", "/nonexistent.json5"], "zenoh config file not found"),
    (["bridge", "--source", "sim", "--connect", "nonsense"], "bad zenoh endpoint"),
    (["bridge", "--rate-scale", "-1"], "must be a non-negative number"),
    (["record"], "required: --out"),
])
def test_user_errors_are_one_line(tpods_exe, args, msg):
    r = run_in_process("mocap", *args)
    assert r.returncode == 2
    assert msg in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert "Traceback" not in r.stderr


def test_sim_source_without_folder_runs_nominal(tpods_exe, tmp_path):
    ep = f"tcp/127.0.0.1:{free_port()}"
    r = run_in_process("mocap", "bridge", "--source", "sim", "--rate-scale", "0", "--listen", ep,
                       "--no-multicast", "--quiet")
    assert r.returncode == 0, r.stderr
    n = int(r.stdout.split("published ")[1].split()[0])
    assert n == 120 * 120 + 1  # 120 s at 120 Hz, nothing dropped
