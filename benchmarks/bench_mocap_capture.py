"""The mocap bridge with ``--capture`` on and off (``make bench-long``: 8 runs take minutes).

Same set-up as ``benchmarks/bench_mocap.py`` (Tracker emulator -> bridge -> Zenoh
subscriber, each a process of its own, same environment variables); the rows are
:func:`benchmarks.bench_mocap.capture_rows`: the bridge's CPU per pose with capture on
against off, interleaved runs, and the latency p99 of both (shown, not judged).
"""

from __future__ import annotations

import multiprocessing as mp
import os

from benchmarks.bench_mocap import _free_port, capture_rows, plain


def run() -> list[dict]:
    seconds = float(os.environ.get("TPODS_BENCH_MOCAP_S", "5"))
    n_bodies = int(os.environ.get("TPODS_BENCH_MOCAP_BODIES", "10"))
    rate_hz = float(os.environ.get("TPODS_BENCH_MOCAP_HZ", "2000"))
    ep = f"tcp/127.0.0.1:{_free_port()}"  # each run's subscriber process listens here
    return plain(capture_rows(mp.get_context("spawn"), ep, n_bodies, rate_hz, seconds))


if __name__ == "__main__":  # pragma: no cover
    for row in run():
        print(row)
