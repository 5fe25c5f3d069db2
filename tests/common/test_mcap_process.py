"""McapProcessLog (common/mcap/process.py): the live estimator's MCAP recording, written by
a process of its own: the same file as McapLog, a clean file after the caller is killed,
and a writer that dies is said at close."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from common.errors import UserError
from common.mcap.log import McapLog, end_status, has_summary, read_mcap
from common.mcap.process import McapProcessLog
from common.wire import encode_command, encode_pose


def _messages(n: int) -> list[tuple[str, bytes, int]]:
    out = []
    for k in range(n):
        t = 100.0 + k * 1e-3
        out.append(("tpods/mocap/b/pose", encode_pose("b", k, t, t, (1, 2, 0, 0, 0, 0, 1, 0.1)),
                    int(t * 1e9) + 5))
        if k % 10 == 0:
            out.append(("tpods/b/cmd", encode_command("b", k, t, [50.0, 0, 0, 50.0]),
                        int(t * 1e9) + 7))
    out.append(("tpods/b/odd", b"not json", int(200e9)))
    return out


def test_the_same_file_as_the_in_process_writer(tmp_path):
    msgs = _messages(500)
    meta = {"command": "test", "keys": {"pose": "tpods/mocap/b/pose"}}
    with McapLog(tmp_path / "a.mcap", meta=meta) as a:
        for m in msgs:
            a.write(*m)
    with McapProcessLog(tmp_path / "b.mcap", meta=meta) as b:
        for m in msgs:
            b.write(*m)
    ra, rb = read_mcap(tmp_path / "a.mcap"), read_mcap(tmp_path / "b.mcap")
    assert ra.complete and rb.complete and len(rb.messages) == len(msgs)
    assert rb.messages == ra.messages  # topics, schemas, encodings, times, sequences, bytes
    assert b.counters["messages"] == a.counters["messages"] == len(msgs)
    assert b.counters["raw"] == a.counters["raw"] == 1
    assert b.topics == a.topics == {"tpods/mocap/b/pose", "tpods/b/cmd", "tpods/b/odd"}
    assert end_status(tmp_path / "b.mcap") == "complete"


def test_flush_puts_what_was_written_in_the_file(tmp_path):
    path = tmp_path / "f.mcap"
    log = McapProcessLog(path)
    try:
        for m in _messages(50):
            log.write(*m)
        log.flush()
        assert len(read_mcap(path).messages) == 56  # 50 poses, 5 commands, 1 raw
    finally:
        log.close()


_KILLED = """
import os, signal, sys
from common.mcap.process import McapProcessLog
from common.wire import encode_pose
log = McapProcessLog(sys.argv[1])
for k in range(300):
    log.write("tpods/mocap/b/pose", encode_pose("b", k, 1.0 + k, 1.0 + k, (0, 0, 0, 0, 0, 0, 1, 0)),
              k + 1)
log.flush()
print(log._proc.pid, flush=True)
os.kill(os.getpid(), signal.SIGKILL)
"""


def test_a_killed_caller_leaves_a_closed_file_marked_incomplete(tmp_path):
    path = tmp_path / "k.mcap"
    r = subprocess.run([sys.executable, "-c", _KILLED, str(path)], capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == -signal.SIGKILL, r.stderr[-2000:]
    writer = int(r.stdout.split()[0])
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline and not has_summary(path):
        time.sleep(0.05)
    assert end_status(path) == "incomplete"  # summary and footer written by the writer
    got = read_mcap(path)
    assert got.complete and [json.loads(m.data)["frame"] for m in got.messages] == list(range(300))
    deadline = time.monotonic() + 10  # and the writer process has ended (no orphan)
    while time.monotonic() < deadline and _running(writer):
        time.sleep(0.05)
    assert not _running(writer)


def _running(pid: int) -> bool:
    """Whether ``pid`` still runs (a zombie, ended but not yet reaped by init, does not)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def test_a_writer_that_dies_is_said_at_close(tmp_path):
    path = tmp_path / "d.mcap"
    log = McapProcessLog(path)
    for m in _messages(20):
        log.write(*m)
    log.flush()
    os.kill(log._proc.pid, signal.SIGKILL)
    log._proc.join(10)
    for m in _messages(20):
        log.write(*m)
    with pytest.raises(UserError, match="writer process ended early.*exit code -9"):
        log.close()


def test_a_path_that_cannot_be_written_is_one_user_error(tmp_path):
    with pytest.raises(UserError, match="cannot write"):
        McapProcessLog(tmp_path / "no" / "such" / "dir.mcap")
