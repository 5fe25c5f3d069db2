"""Thrust bench: serial capture cost, valve-closing latencies.

Emulators run in this process on ptys (realistic balance: 0.3 s lag, 0.2 g noise,
10 Hz printing, drift, unstable and garbage lines); the session runs as the
installed ``tpods bench characterize`` in a subprocess, as a user runs it. A full
characterisation (session overhead, fit accuracy against Table 2) takes minutes:
``benchmarks/bench_session.py`` (``make bench-long``).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.emulators import EmulatedScout, EmulatedValveController, serve_pty
from benchmarks.host import Window

EXE = str(Path(sys.executable).with_name("tpods"))


def _bench(seed: int = 0, **kw):
    ev = EmulatedValveController(4)
    es = EmulatedScout(ev, seed=seed, **kw)
    return ev, es, serve_pty(ev), serve_pty(es)


def _session(out: Path, vs, ss, *args: str) -> subprocess.Popen:
    return subprocess.Popen([EXE, "bench", "characterize", "--valves", vs.path, "--scale", ss.path,
                             "--out", str(out), "--no-progress", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _kill(tmp: Path, sig: int, name: str) -> float:
    """Seconds from the signal to all valves closed (emulator log)."""
    ev, es, vs, ss = _bench(seed=1, lag_s=0.02, print_rate_hz=50)
    try:
        p = _session(tmp / name, vs, ss, "--nozzles", "2", "--duty", "50", "--dwell", "3",
                     "--settle", "0.1", "--zero-settle", "0.1", "--zero-dwell", "0.1",
                     "--watchdog-ms", "500")
        end = time.monotonic() + 30
        while not any(ev.duties):
            if time.monotonic() > end or p.poll() is not None:
                raise RuntimeError("valves never opened")
            time.sleep(0.005)
        time.sleep(1.0)
        t0 = time.monotonic()
        os.kill(p.pid, sig)
        p.communicate(timeout=30)
        while any(ev.duties) and time.monotonic() < t0 + 5:
            time.sleep(0.005)
        closing = next(c for c in ev.log if c.t > t0)
        return closing.t - t0
    finally:
        ss.stop()
        vs.stop()


def _capture_rows(tmp: Path) -> list[dict]:
    """A short session (100 Hz prints) with serial capture on and off, alternated; and the
    cost of writing one transcript line."""
    from bench.capture import Transcript
    from bench.ohaus.driver import OhausScout
    from bench.session import SessionConfig, run_session
    from bench.valves import ValveController

    cfg = SessionConfig(nozzles=(1, 2), duties_pct=(30, 60, 90), dwell_s=0.3, settle_s=0.1,
                        zero_settle_s=0.1, zero_dwell_s=0.1, watchdog_ms=300)
    loop = {False: [], True: []}
    w = Window()
    for i in range(4):
        cap = bool(i % 2)
        ev, es, vs, ss = _bench(seed=i, lag_s=0.02, print_rate_hz=100)
        out = tmp / f"cap{i}"
        try:
            with ValveController(vs.path, capture=out / "v.serial.jsonl" if cap else None) as v, \
                    OhausScout(ss.path, capture=out / "s.serial.jsonl" if cap else None) as s:
                run_session(v, s, cfg, out, progress=False)
        finally:
            ss.stop()
            vs.stop()
        loop[cap].append(json.loads((out / "run.json").read_text())["timing"]["loop_s"] - cfg.planned_s)
    w.stop()
    off, on = float(np.median(loop[False])), float(np.median(loop[True]))
    tr = Transcript(tmp / "x.serial.jsonl", device="x", url="x", settings={}, t_open=time.monotonic())
    n = 20000
    w_line = Window()
    t0 = time.perf_counter()
    for _ in range(n):
        tr.chunk(time.monotonic(), "rx", b"     12.34 g ?\r\n", False, 1.0)
    per = (time.perf_counter() - t0) / n
    w_line.stop()
    tr.close()
    return [
        {"case": "bench session, serial capture on/off", "metric": "loop time beyond plan, on - off (ms)",
         "value": 1000 * (on - off), "reference": 10.0, "ratio": 10.0 / max(abs(1000 * (on - off)), 1e-3),
         "ok": 1000 * (on - off) < 10.0, "target": f"< 10 ms (off {1000 * off:.1f} ms, on {1000 * on:.1f} ms)",
         **w.timed()},
        {"case": "serial capture", "metric": "cost of one transcript line (us)",
         "value": 1e6 * per, "reference": 10.0, "ratio": 10.0 / (1e6 * per), "ok": per < 10e-6,
         "target": "< 10 us (write + flush per line)", **w_line.timed()},
    ]


def run() -> list[dict]:
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        rows = _capture_rows(tmp)
        w = Window()
        lat = [_kill(tmp, signal.SIGINT, f"int{i}") for i in range(3)]
        rows.append({"case": "bench Ctrl-C", "metric": "signal to valves closed, worst of 3 (ms)",
                     "value": 1000 * max(lat), "reference": 200.0, "ratio": 200.0 / (1000 * max(lat)),
                     "ok": max(lat) < 0.2, "target": "< 200 ms", **w.timed()})
        w = Window()
        k9 = _kill(tmp, signal.SIGKILL, "kill9")
        rows.append({"case": "bench kill -9", "metric": "kill to watchdog close (ms)",
                     "value": 1000 * k9, "reference": 500.0, "ratio": 500.0 / (1000 * k9),
                     "ok": k9 <= 0.5 + 1e-3, "target": "<= watchdog (500 ms)", **w.timed()})
    return rows


if __name__ == "__main__":
    for r in run():
        print(r)
