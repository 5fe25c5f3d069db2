"""--capture on the commands that open serial links (issue 19), and their transcripts
replayed with replay:// through the same commands."""

import json
import subprocess

import pytest

from bench.capture import read_transcript
from bench.emulators import EmulatedScout, EmulatedValveController, serve_pty
from tests.support.bench import Bench, start_session
from tests.support.cli import run_in_process


def _run(*args, timeout=120):
    return subprocess.run(list(args), capture_output=True, text=True, timeout=timeout)


def test_characterize_captures_both_links_into_the_run_folder_and_replays(tpods_exe, tmp_path):
    b = Bench(seed=2)
    out = tmp_path / "run"
    try:
        p = start_session(tpods_exe, b, out, "--nozzles", "1", "--duty", "50,90", "--dwell", "0.2",
                          "--settle", "0.1", "--zero-settle", "0.1", "--zero-dwell", "0.1", "--capture")
        stdout, stderr = p.communicate(timeout=120)
    finally:
        b.stop()
    assert p.returncode == 0, stderr
    assert "serial transcripts" in stdout
    hv, ev = read_transcript(out / "valves.serial.jsonl")
    hs, es = read_transcript(out / "scale.serial.jsonl")
    assert hv["device"] == "valve controller" and hs["device"] == "OHAUS balance"
    assert any(data.startswith(b"DUTY* 90") for _, d, data, _, _ in ev if d == "tx")
    assert json.loads((out / "run.json").read_text())["valves_closed_confirmed"] is True
    # the transcripts drive the same command again, as devices
    r = run_in_process("bench", "characterize", "--valves", f"replay://{out}/valves.serial.jsonl",
             "--scale", f"replay://{out}/scale.serial.jsonl", "--nozzles", "1", "--duty", "50,90",
             "--dwell", "0.2", "--settle", "0.1", "--zero-settle", "0.1", "--zero-dwell", "0.1",
             "--out", str(tmp_path / "again"), "--no-progress")
    assert r.returncode == 0, r.stderr
    assert "session success: 2 steps" in r.stdout
    # a changed command fails in one line naming the exchange
    r = run_in_process("bench", "characterize", "--valves", f"replay://{out}/valves.serial.jsonl",
             "--scale", f"replay://{out}/scale.serial.jsonl", "--nozzles", "1", "--duty", "50,80",
             "--dwell", "0.2", "--settle", "0.1", "--zero-settle", "0.1", "--zero-dwell", "0.1",
             "--out", str(tmp_path / "changed"), "--no-progress")
    assert r.returncode == 2, r.stderr
    assert r.stderr.startswith("tpods: error: ") and "the recording has b'DUTY* 90 0 0 0\\n'" in r.stderr
    assert "the host sent b'DUTY* 80 0 0 0\\n'" in r.stderr


def test_characterize_capture_dir_refuses_existing_transcripts(tpods_exe, tmp_path):
    d = tmp_path / "cap"
    d.mkdir()
    (d / "valves.serial.jsonl").write_text("{}\n")
    r = run_in_process("bench", "characterize", "--valves", "/dev/null/x", "--scale", "/dev/null/y",
             "--out", str(tmp_path / "run"), "--capture", str(d))
    assert r.returncode == 2 and "already holds valves.serial.jsonl" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_calibrate_mass_capture_replays_to_the_same_mass(tpods_exe, tmp_path):
    scout = EmulatedScout(None, load_g=812.5, lag_s=0.02, print_rate_hz=100, seed=3, unstable_prob=0.2)
    srv = serve_pty(scout)
    cap = tmp_path / "mass.jsonl"
    try:
        r = _run(tpods_exe, "calibrate", "mass", "--scale", srv.path, "--readings", "4", "--json",
                 "--capture", str(cap))
    finally:
        srv.stop()
    assert r.returncode == 0, r.stderr
    live = json.loads(r.stdout)
    r = run_in_process("calibrate", "mass", "--scale", f"replay://{cap}", "--readings", "4", "--json")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["mass_kg"] == live["mass_kg"]
    r = run_in_process("calibrate", "mass", "--values", "1,2", "--capture", str(tmp_path / "x.jsonl"))
    assert r.returncode == 2 and "needs --scale" in r.stderr


def test_run_play_captures_into_its_out_folder(tpods_exe, tmp_path):
    valves = EmulatedValveController(4)
    srv = serve_pty(valves)
    out = tmp_path / "play"
    try:
        r = _run(tpods_exe, "run", "play", "--valves", srv.path, "--duration", "0.5", "--out", str(out),
                 "--capture", "--no-progress", "--no-multicast")
    finally:
        srv.stop()
    if "--no-multicast" in r.stderr and r.returncode == 2:
        pytest.skip("run play has no --no-multicast here")
    assert r.returncode == 0, r.stderr
    _, ev = read_transcript(out / "valves.serial.jsonl")
    tx = [data for _, d, data, _, _ in ev if d == "tx"]
    assert tx[-2:] == [b"OFF\n", b"STATE?\n"]                 # closed on exit, on the record
    r = run_in_process("run", "play", "--valves", "/dev/null/x", "--capture")
    assert r.returncode == 2 and "--capture without a folder" in r.stderr


def test_sigkill_loses_at_most_the_last_tenth_of_a_second_of_a_transcript(tpods_exe, tmp_path):
    """issue 19: a capture killed outright (SIGKILL, no clean-up) is readable to its last
    whole line, and that line is less than 0.1 s older than the kill. Chunks the host saw in
    that last 0.1 s may be lost; none before."""
    import os
    import signal
    import time

    b = Bench(seed=3)
    out = tmp_path / "run"
    try:
        p = start_session(tpods_exe, b, out, "--nozzles", "1", "--duty", "30:90:10", "--dwell",
                          "2", "--settle", "0.2", "--capture")
        path = out / "scale.serial.jsonl"
        end = time.monotonic() + 30
        while time.monotonic() < end and (not path.exists() or path.stat().st_size < 2000):
            time.sleep(0.05)
        time.sleep(0.5)  # the balance prints at 50 Hz: lines arrive all the time
        t_kill = time.monotonic()
        os.kill(p.pid, signal.SIGKILL)
        p.wait(10)
    finally:
        b.stop()
    for name in ("valves.serial.jsonl", "scale.serial.jsonl"):
        header, events = read_transcript(out / name)  # every line but a cut last one reads
        assert events, name
    header, events = read_transcript(out / "scale.serial.jsonl")
    last = header["t_open_monotonic"] + events[-1][0]
    assert 0 <= t_kill - last < 0.1, t_kill - last
