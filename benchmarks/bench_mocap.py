"""Mocap bridge throughput and latency: Vicon UDP -> bridge -> Zenoh subscriber on loopback.

Three spawned processes, none of them the bench runner: a Tracker UDP emulator sending
10 bodies at 2 kHz (20,000 poses/s), the bridge (UDP source -> Zenoh peer) and the Zenoh
subscriber (fresh, garbage collector off, see :func:`_sub_proc`). Latency is subscriber
receive time minus the emulator's send time of the datagram (same host clock), so it
includes the UDP hop, parsing, encoding and Zenoh. Reference, measured in the same run:
raw Zenoh ``put`` of the same payloads from a Python publisher process to the same kind
of subscriber (maximum rate, and latency when paced at the bridge's rate). Both
publishers use the tpods Zenoh settings (transmit batching limit 0 ms, see
:mod:`common.zenoh_net`).

Host interference. This is a virtual machine: the hypervisor sometimes takes a virtual
CPU away for milliseconds ("steal" time in ``/proc/stat``). Every thread on that CPU
stalls, whatever code it runs, and the poses sent meanwhile queue up. Measured here
(5 s runs, same code): runs with 0.1 % steal had p99 1.1-2.1 ms (one 3.9 ms); runs
with 2.3-3.7 % steal had p99 4.8-7.2 ms, the raw Zenoh reference alike. A p99 is the
1 % tail, so a run in which the host stole 0.5 % or more of the CPU time cannot show
what the bridge does at p99 (``QUIET_STEAL_PCT``). The bench therefore records the
steal of every run, keeps running (up to ``TPODS_BENCH_MOCAP_MAX_RUNS``, default three
times the repeats) until ``TPODS_BENCH_MOCAP_REPEATS`` (default 5) quiet runs are in,
and judges the latency on the pooled poses of the quiet runs. Noisy runs are listed,
not hidden; with fewer than ``MIN_QUIET`` quiet runs the latency row is not judged
(``ok`` None, the reason in the row). Zero loss is required in every run, noisy or not
(though when other processes load the host, the runner calls a loss "noisy host": the
bridge then gets too little CPU to drain its socket; docs/bench.md).

Environment: ``TPODS_BENCH_MOCAP_S`` (seconds of load per run, default 5),
``TPODS_BENCH_MOCAP_BODIES`` (default 10), ``TPODS_BENCH_MOCAP_HZ`` (default 2000),
``TPODS_BENCH_MOCAP_BATCH_MS`` (Zenoh batching limit of both publishers; zenoh's own
default is 1), ``TPODS_BENCH_MOCAP_REPEATS``, ``TPODS_BENCH_MOCAP_MAX_RUNS``,
``TPODS_BENCH_MOCAP_CAPTURE_RUNS`` (pairs of capture off/on runs, default 4, of
:func:`capture_rows`: the case ``benchmarks/bench_mocap_capture.py``, ``make bench-long``).
"""

from __future__ import annotations

import gc
import multiprocessing as mp
import os
import socket
import threading
import time

import numpy as np

from benchmarks.host import Window
from common.zenoh_net import keep_thread_state

TARGET_POSES_S = 20_000
TARGET_P99_MS = 2.0
QUIET_STEAL_PCT = 0.5
"""A run whose host steal time reached this share of the CPU time is not used to judge p99."""
MIN_QUIET = 3


def cpu_ticks() -> tuple[int, int] | None:
    """(steal, total) CPU ticks of all CPUs from ``/proc/stat``; None where unavailable."""
    try:
        with open("/proc/stat") as f:
            v = [int(x) for x in f.readline().split()[1:9]]
    except (OSError, ValueError):
        return None
    if len(v) < 8:
        return None
    return v[7], sum(v)  # user nice system idle iowait irq softirq steal


def steal_pct(before: tuple[int, int] | None, after: tuple[int, int] | None) -> float:
    """Share of CPU time the hypervisor took between two :func:`cpu_ticks` readings, %
    (0 where not measurable: bare metal or no /proc)."""
    if before is None or after is None or after[1] <= before[1]:
        return 0.0
    return 100.0 * (after[0] - before[0]) / (after[1] - before[1])


def run_delay_s() -> float | None:
    """Time the calling thread has spent runnable but not running (waiting for a CPU), s,
    from ``/proc/thread-self/schedstat``; None where unavailable."""
    try:
        with open("/proc/thread-self/schedstat") as f:
            return int(f.read().split()[1]) * 1e-9
    except (OSError, ValueError, IndexError):
        return None


def _free_port(kind=socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _batch_ms() -> int | None:
    """Zenoh transmit batching limit for the bridge and the raw publisher (same for both)."""
    v = os.environ.get("TPODS_BENCH_MOCAP_BATCH_MS")
    return int(v) if v else None


def _pace(due: float) -> None:
    """Sleep until ``due`` (perf_counter); no spinning (the machine has 2 cores)."""
    left = due - time.perf_counter()
    if left > 0:
        time.sleep(left)


# ------------------------------------------------------------------ child processes


def _bridge_proc(port: int, ep: str, ready, stop, out, capture: str | None = None) -> None:
    from common.zenoh_net import open_session
    from mocap_bridge.bridge import Bridge
    from mocap_bridge.sources.vicon_udp import ViconUDPSource

    session = open_session(connect=[ep], no_multicast=True, zenoh_batch_ms=_batch_ms())
    src = ViconUDPSource(port=port, bind="127.0.0.1", capture=capture)
    bridge = Bridge(session, prefix="bench/mocap",
                    express=os.environ.get("TPODS_BENCH_MOCAP_EXPRESS", "0") == "1")
    ok = bridge.wait_for_subscriber(20.0)
    ready.set()
    stop_ev = threading.Event()
    threading.Thread(target=lambda: (stop.wait(), stop_ev.set()), daemon=True).start()
    t0, q0 = time.process_time(), run_delay_s()
    bridge.run(src, stop=stop_ev)
    cpu, q1 = time.process_time() - t0, run_delay_s()
    runq = None if q0 is None or q1 is None else q1 - q0
    out.put({"matched": ok, "cpu_s": cpu, "runq_s": runq, **bridge.stats.totals(), **src.counters})
    src.close()
    session.close()


def _sender_proc(port: int, n_bodies: int, rate_hz: float, seconds: float, go, out) -> None:
    from mocap_bridge.sources.vicon_udp import tracker_datagrams

    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    dest = ("127.0.0.1", port)
    n = int(seconds * rate_hz)
    names = [f"body{j:02d}" for j in range(n_bodies)]
    # as Tracker sends them: object items (type 0) in blocks padded to the Data Block Size
    block = int(os.environ.get("TPODS_BENCH_MOCAP_BLOCK", "1024"))
    datagrams = [tracker_datagrams(
        f + 1, [(0, names[j], (1000.0 + f, -500.0 + j, 30.0, 0.01, -0.02, 0.001 * f))
                for j in range(n_bodies)], block) for f in range(n)]
    send_t = np.empty(n)
    go.wait()
    start = time.perf_counter() + 0.05
    for f in range(n):
        _pace(start + f / rate_hz)
        send_t[f] = time.time()
        for d in datagrams[f]:
            sock.sendto(d, dest)
    out.put(send_t)


def _raw_proc(ep: str, n: int, rate_hz: float, go, out) -> None:
    import zenoh

    from common.zenoh_net import open_session
    from mocap_bridge.pose import encode_pose, yaw_quat

    session = open_session(connect=[ep], no_multicast=True, zenoh_batch_ms=_batch_ms())
    pub = session.declare_publisher("bench/raw/body/pose", encoding=zenoh.Encoding("application/json"),
                                    congestion_control=zenoh.CongestionControl.BLOCK)
    deadline = time.monotonic() + 20
    while not getattr(pub.matching_status, "matching", False) and time.monotonic() < deadline:
        time.sleep(0.01)
    q = yaw_quat(0.3)
    pose = (1.0, -0.5, 0.03, *q, 0.3)
    go.wait()
    start = time.perf_counter() + 0.05
    t0 = time.time()
    for k in range(n):
        if rate_hz:
            _pace(start + k / rate_hz)
        t = time.time()
        pub.put(encode_pose("body00", k, t, t, pose))
    out.put(time.time() - t0)
    time.sleep(0.5)
    session.close()


# ------------------------------------------------------------------ measurement


class _Sink:
    """Keeps every (payload, receive time), counting in shared memory for the orchestrator.

    Payloads are copied into one buffer allocated and touched before the run, so the
    receive thread allocates nothing that outlives a sample (no heap growth, no page
    faults during the measurement). ``capacity`` samples of up to 512 bytes on average."""

    def __init__(self, count, capacity: int) -> None:
        self.buf = np.ones(capacity * 512, dtype=np.uint8)  # ones: every page touched now
        self.mv = memoryview(self.buf)
        self.ends = np.full(capacity, -1, dtype=np.int64)
        self.ts = np.full(capacity, np.nan)
        self.k = 0
        self.off = 0
        self.overflow = 0
        self.count = count

    def __call__(self, sample) -> None:
        b = sample.payload.to_bytes()
        t = time.time()
        k, o = self.k, self.off
        e = o + len(b)
        if k >= len(self.ts) or e > len(self.buf):
            self.overflow += 1
            return
        self.mv[o:e] = b
        self.ends[k] = e
        self.ts[k] = t
        self.k = k + 1
        self.off = e
        self.count.value += 1

    def payloads(self):
        start = 0
        for k in range(self.k):
            e = int(self.ends[k])
            yield bytes(self.mv[start:e]), float(self.ts[k])
            start = e


def _handler(sink: _Sink):
    """Run the sink in Zenoh's receive thread (no hand-over to a Python thread), unless
    TPODS_BENCH_MOCAP_INDIRECT=1. Same subscriber for the bridge and the reference."""
    import zenoh

    indirect = os.environ.get("TPODS_BENCH_MOCAP_INDIRECT", "0") == "1"
    return zenoh.handlers.Callback(keep_thread_state(sink), indirect=indirect)


def _sub_proc(ep: str, key: str, count, ready, stop, out, capacity: int = 0) -> None:
    """The measuring subscriber, in a fresh process of its own (nothing else runs in it).

    Python's cyclic garbage collector is off here: when the sink kept each sample as
    objects, a collection pass over them stalled the receive thread for tens of ms,
    latency that is the harness's and not the bridge's. Decodes at the end and
    returns arrays: frame, capture time, bridge receive time, subscriber receive time."""
    from common.zenoh_net import open_session
    from mocap_bridge.pose import decode_pose

    gc.disable()
    session = open_session(listen=[ep], no_multicast=True)
    sink = _Sink(count, capacity)
    sub = session.declare_subscriber(key, _handler(sink))
    ready.set()
    stop.wait()
    sub.undeclare()
    items = list(sink.payloads())
    n = len(items)
    frame = np.empty(n, dtype=np.int64)
    cols = np.empty((n, 3))
    bodies: list[str] = []
    k = 0
    for b, ts in items:
        d = decode_pose(b)
        if d is None:
            continue
        frame[k] = d["frame"]
        cols[k] = (d["t"], d["t_recv"], ts)
        bodies.append(d["body"])
        k += 1
    out.put({"frame": frame[:k], "t": cols[:k, 0], "t_recv": cols[:k, 1], "t_sub": cols[:k, 2],
             "body": bodies, "bad": n - k, "overflow": sink.overflow})
    session.close()


class _Subscriber:
    """Start :func:`_sub_proc`; ``wait(n)`` until n samples arrived; ``result()``."""

    def __init__(self, ctx, ep: str, key: str, capacity: int) -> None:
        self.count = ctx.Value("q", 0, lock=False)
        self.stop, ready, self.out = ctx.Event(), ctx.Event(), ctx.Queue()
        self.p = ctx.Process(target=_sub_proc,
                             args=(ep, key, self.count, ready, self.stop, self.out, capacity))
        self.p.start()
        if not ready.wait(60):
            self.p.terminate()
            raise RuntimeError("subscriber process did not start")

    def wait(self, expected: int, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while self.count.value < expected and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.2)

    def result(self) -> dict:
        self.stop.set()
        try:
            r = self.out.get(timeout=120)
            if r["overflow"]:
                raise RuntimeError(f"bench harness: subscriber buffer overflowed ({r['overflow']} samples)")
            return r
        finally:
            self.p.join(30)
            if self.p.is_alive():
                self.p.terminate()


def _raw(ctx, ep: str, n: int, rate_hz: float) -> dict:
    sub = _Subscriber(ctx, ep, "bench/raw/**", n + 1000)
    go, out = ctx.Event(), ctx.Queue()
    p = ctx.Process(target=_raw_proc, args=(ep, n, rate_hz, go, out))
    p.start()
    time.sleep(0.5)
    go.set()
    sub.wait(n, 60 + n / 5000)
    send_s = out.get(timeout=120)
    p.join(30)
    r = sub.result()
    recv = r["t_sub"]
    span = recv.max() - recv.min() if len(recv) > 1 else float("nan")
    return {"received": len(recv), "sent": n, "rate": (len(recv) - 1) / span,
            "send_rate": n / send_s, "lat_ms": (recv - r["t"]) * 1e3}


def _bridge_once(ctx, ep: str, n_bodies: int, rate_hz: float, seconds: float,
                 capture: str | None = None) -> dict:
    """One bridge run: sender -> bridge -> subscriber. Latencies in ms per delivered pose.
    ``capture``: the bridge also writes the datagrams to this pcap file (--capture)."""
    sub = _Subscriber(ctx, ep, "bench/mocap/**", int(seconds * rate_hz * n_bodies) + 1000)
    port = _free_port(socket.SOCK_DGRAM)
    ready, stop, go = ctx.Event(), ctx.Event(), ctx.Event()
    bout, sout = ctx.Queue(), ctx.Queue()
    bp = ctx.Process(target=_bridge_proc, args=(port, ep, ready, stop, bout, capture))
    sp = ctx.Process(target=_sender_proc, args=(port, n_bodies, rate_hz, seconds, go, sout))
    bp.start()
    sp.start()
    try:
        if not ready.wait(60):
            raise RuntimeError("bridge process did not start")
        time.sleep(0.3)
        ticks0 = cpu_ticks()
        go.set()
        send_t = sout.get(timeout=seconds * 10 + 60)
        ticks1 = cpu_ticks()
        sp.join(30)
        n_sent = len(send_t) * n_bodies
        sub.wait(n_sent, 30)
        stop.set()
        bstats = bout.get(timeout=60)
        bp.join(30)
        r = sub.result()
    finally:
        for p in (sp, bp, sub.p):
            if p.is_alive():
                p.terminate()
    frames, t_sub = r["frame"], r["t_sub"]
    seen = set(zip(r["body"], frames.tolist(), strict=True))
    sent = send_t[frames - 1]
    span = send_t[-1] - send_t[0]
    return {
        "lat_ms": (t_sub - sent) * 1e3, "udp_ms": (r["t_recv"] - sent) * 1e3,
        "n_sent": n_sent, "lost": n_sent - len(seen),
        "sent_rate": (n_sent - n_bodies) / span if span > 0 else float("nan"),
        "delivered_rate": len(seen) / (t_sub.max() - sent.min()) if len(t_sub) else 0.0,
        "bstats": bstats, "steal_pct": steal_pct(ticks0, ticks1),
    }


def _p(x: np.ndarray, q: float) -> float:
    return float(np.percentile(x, q)) if len(x) else float("nan")


CAPTURE_MAX_SLOWDOWN = 1.05
"""--capture may cost the bridge at most 5 % more CPU per pose."""


def capture_rows(ctx, ep: str, n_bodies: int, rate_hz: float, seconds: float) -> list[dict]:
    """The bridge with ``--capture`` on and off, runs interleaved (off on, on off, off on,
    ...; ``TPODS_BENCH_MOCAP_CAPTURE_RUNS`` pairs, default 4): bridge CPU per pose (the
    median run of each), p99 latency pooled, loss, and that the file holds every datagram."""
    import tempfile

    pairs = int(os.environ.get("TPODS_BENCH_MOCAP_CAPTURE_RUNS", "4"))
    w = Window()
    res: dict[bool, list[dict]] = {False: [], True: []}
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(pairs):
            for on in ((False, True) if k % 2 == 0 else (True, False)):  # no order bias
                cap = os.path.join(tmp, f"run{k}.pcap") if on else None
                r = _bridge_once(ctx, ep, n_bodies, rate_hz, seconds, capture=cap)
                b = r["bstats"]
                r["cpu_us"] = b["cpu_s"] / max(b["published"], 1) * 1e6
                if on:
                    size = os.path.getsize(cap)
                    r["file_ok"] = b.get("captured") == b["datagrams"] and b.get("capture_errors") == 0
                    r["file_mb"] = size / 1e6
                res[on].append(r)
                print(f"  capture {'on ' if on else 'off'} run {k + 1}: {r['cpu_us']:.1f} us/pose, "
                      f"p99 {_p(r['lat_ms'], 99):.2f} ms, steal {r['steal_pct']:.2f} %, lost {r['lost']}",
                      flush=True)
    w.stop()
    cpu = {on: float(np.median([r["cpu_us"] for r in rs])) for on, rs in res.items()}
    p99 = {on: _p(np.concatenate([r["lat_ms"] for r in rs]), 99) for on, rs in res.items()}
    lost = sum(r["lost"] for rs in res.values() for r in rs)
    file_ok = all(r["file_ok"] for r in res[True])
    mb_s = float(np.mean([r["file_mb"] for r in res[True]])) / seconds
    ratio = cpu[False] / cpu[True]
    each = {on: ", ".join(f"{r['cpu_us']:.1f}" for r in rs) for on, rs in res.items()}
    case = f"mocap bridge --capture {n_bodies}x{rate_hz:g} Hz"
    return [
        {"case": case, "metric": "bridge CPU us/pose, capture on",
         "value": cpu[True], "reference": cpu[False], "ratio": ratio,
         "ok": bool(cpu[True] <= CAPTURE_MAX_SLOWDOWN * cpu[False] and lost == 0 and file_ok),
         "target": f"<= {CAPTURE_MAX_SLOWDOWN:.2f} x capture off (median of {pairs} interleaved "
                   f"runs each; off: {each[False]}, on: {each[True]}); zero loss (lost {lost}); "
                   f"every datagram in the file ({'yes' if file_ok else 'NO'}, {mb_s:.2f} MB/s)",
         **w.timed(ok_untimed=file_ok)},
        {"case": case, "metric": "latency p99 ms, capture on",
         "value": p99[True], "reference": p99[False],
         "ratio": p99[False] / p99[True] if p99[True] > 0 else 0.0, "ok": None,
         "target": "shown, not judged: p99 of runs this short moves with the host (see the "
                   "bridge rows); pooled over the same interleaved runs", **w.timed()},
    ]


def run() -> list[dict]:
    seconds = float(os.environ.get("TPODS_BENCH_MOCAP_S", "5"))
    n_bodies = int(os.environ.get("TPODS_BENCH_MOCAP_BODIES", "10"))
    rate_hz = float(os.environ.get("TPODS_BENCH_MOCAP_HZ", "2000"))
    repeats = int(os.environ.get("TPODS_BENCH_MOCAP_REPEATS", "5"))
    max_runs = max(repeats, int(os.environ.get("TPODS_BENCH_MOCAP_MAX_RUNS", str(3 * repeats))))
    offered = n_bodies * rate_hz
    ctx = mp.get_context("spawn")
    ep = f"tcp/127.0.0.1:{_free_port()}"  # the subscriber process listens, publishers connect
    w = Window()
    raw_max = _raw(ctx, ep, int(min(offered * 3, 60000)), 0.0)
    raw_paced = _raw(ctx, ep, int(offered * min(seconds, 3.0)), offered)
    runs: list[dict] = []
    while len(runs) < max_runs and sum(r["steal_pct"] < QUIET_STEAL_PCT for r in runs) < repeats:
        r = _bridge_once(ctx, ep, n_bodies, rate_hz, seconds)
        runs.append(r)
        print(f"  bridge run {len(runs)}: p99 {_p(r['lat_ms'], 99):.2f} ms, host steal "
              f"{r['steal_pct']:.2f} %, lost {r['lost']}", flush=True)
    w.stop()

    quiet = [r for r in runs if r["steal_pct"] < QUIET_STEAL_PCT]
    judged = quiet if len(quiet) >= MIN_QUIET else runs
    lat = np.concatenate([r["lat_ms"] for r in judged])
    udp = np.concatenate([r["udp_ms"] for r in judged])
    p99, p50, udp99 = _p(lat, 99), _p(lat, 50), _p(udp, 99)
    raw_p99 = _p(raw_paced["lat_ms"], 99)
    published = sum(x["bstats"]["published"] for x in runs)
    cpu_us = sum(x["bstats"]["cpu_s"] for x in runs) / max(published, 1) * 1e6
    lost = sum(x["lost"] for x in runs)
    n_sent = sum(x["n_sent"] for x in runs)
    malformed = sum(x["bstats"]["malformed"] for x in runs)
    sent_rate = min(x["sent_rate"] for x in runs)
    delivered = min(x["delivered_rate"] for x in runs)
    ok_rate = lost == 0 and sent_rate >= 0.98 * TARGET_POSES_S
    each = ", ".join(f"{_p(r['lat_ms'], 99):.2f}{'' if r['steal_pct'] < QUIET_STEAL_PCT else '*'}"
                     for r in runs)
    runq = ", ".join("?" if r["bstats"].get("runq_s") is None else f"{r['bstats']['runq_s'] * 1e3:.0f}"
                     for r in runs)
    steals = ", ".join(f"{r['steal_pct']:.1f}" for r in runs)
    if len(quiet) >= MIN_QUIET:
        ok_lat: bool | None = bool(p99 < TARGET_P99_MS)
        judged_txt = f"pooled over the {len(quiet)} quiet runs of {len(runs)}"
    else:
        ok_lat = None
        judged_txt = (f"NOT JUDGED: only {len(quiet)} of {len(runs)} runs had host steal "
                      f"< {QUIET_STEAL_PCT} %; value pooled over all runs")
    rows = [
        {"case": f"mocap bridge {n_bodies}x{rate_hz:g} Hz", "metric": "poses/s delivered (UDP->zenoh)",
         "value": delivered, "reference": raw_max["rate"],
         "ratio": delivered / raw_max["rate"], "ok": ok_rate,
         "target": f">= {TARGET_POSES_S} poses/s, zero loss ({len(runs)} runs of {seconds:g} s; "
                   f"slowest shown): offered {sent_rate:.0f}/s, lost {lost} of {n_sent}, malformed "
                   f"{malformed}; reference = raw zenoh put max {raw_max['rate']:.0f}/s "
                   f"({raw_max['received']}/{raw_max['sent']}); bridge CPU {cpu_us:.1f} us/pose "
                   f"on {os.cpu_count()} cpus", **w.timed()},
        {"case": f"mocap bridge {n_bodies}x{rate_hz:g} Hz", "metric": "added latency p99, ms",
         "value": p99, "reference": raw_p99, "ratio": raw_p99 / p99 if p99 > 0 else 0.0,
         "ok": ok_lat,
         "target": f"< {TARGET_P99_MS} ms at p99, UDP send to subscriber ({judged_txt}; p50 "
                   f"{p50:.2f} ms, UDP->bridge p99 {udp99:.2f} ms); p99 of each run: {each} ms "
                   f"(* = host steal >= {QUIET_STEAL_PCT} %; steal %: {steals}); queue wait (the "
                   f"bridge thread runnable, not running) per run: {runq} ms; reference = raw "
                   f"zenoh put p99 paced at {offered:.0f}/s ({raw_paced['received']}/"
                   f"{raw_paced['sent']})", **w.timed()},
    ]
    return plain(rows)


def plain(rows: list[dict]) -> list[dict]:
    """Rows with plain Python types for the JSON report."""
    for row in rows:  # plain Python types for the JSON report
        for key in ("value", "reference", "ratio"):
            row[key] = float(row[key])
        row["ok"] = row["ok"] if row["ok"] is None else bool(row["ok"])
    return rows


if __name__ == "__main__":  # pragma: no cover
    for row in run():
        print(row)
