"""McapLog writes off the receiving thread: a queue that never loses a message on stop.

``McapLog.write`` runs in Zenoh callbacks and inside a session's own ``put``; it must
neither parse nor wait for the file (the live estimator's latency, issue 26), and
whatever it accepted must be in the file after ``close`` (or ``flush``)."""

from __future__ import annotations

import threading
import time

from common.mcap.log import McapLog, read_mcap
from common.wire import encode_pose


def _pose(frame: int) -> bytes:
    return encode_pose("b", frame, 10.0 + frame * 1e-3, 10.0 + frame * 1e-3, (1, 2, 0, 0, 0, 0, 1, 0))


def test_write_does_not_wait_for_the_file(tmp_path):
    log = McapLog(tmp_path / "x.mcap", flush_every_s=30.0)
    try:
        with log._lock:  # the writer is busy (a chunk being compressed and written)
            done = threading.Event()
            t = threading.Thread(target=lambda: (log.write("tpods/mocap/b/pose", _pose(1), 1000),
                                                 done.set()))
            t.start()
            assert done.wait(2.0), "write() waited for the background writer"
            t.join()
        assert log.counters["messages"] == 0  # queued, not yet parsed or written
        log.flush()
        assert log.counters["messages"] == 1
    finally:
        log.close()
    assert [m.log_time for m in read_mcap(tmp_path / "x.mcap").messages] == [1000]


def test_nothing_is_lost_on_stop_with_concurrent_writers(tmp_path):
    path = tmp_path / "x.mcap"
    n, writers = 3000, 3
    log = McapLog(path, flush_every_s=0.01, max_pending=50)  # small bound: overflow path too

    def write_all(w: int) -> None:
        for k in range(1, n + 1):
            log.write(f"tpods/mocap/b{w}/pose", _pose(k), w * 10**9 + k)

    ts = [threading.Thread(target=write_all, args=(w,)) for w in range(writers)]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    log.close()  # right after the last write: the queue still holds messages
    r = read_mcap(path)
    assert r.complete
    assert log.counters["messages"] == n * writers and not log.counters.get("write_errors")
    for w in range(writers):
        got = [m for m in r.messages if m.topic == f"tpods/mocap/b{w}/pose"]
        # every message, in the order written, numbered 1..n on its channel
        assert [m.log_time - w * 10**9 for m in got] == list(range(1, n + 1))
        assert [m.sequence for m in got] == list(range(1, n + 1))


def test_background_writer_keeps_the_file_current(tmp_path):
    """Without close: what was written more than a flush period ago is in the file (what
    a kill would leave)."""
    path = tmp_path / "x.mcap"
    log = McapLog(path, flush_every_s=0.02)
    try:
        for k in range(1, 201):
            log.write("tpods/mocap/b/pose", _pose(k), k)
        time.sleep(0.3)  # fifteen flush periods
        r = read_mcap(path)
        assert not r.complete and [m.log_time for m in r.messages] == list(range(1, 201))
    finally:
        log.close()
