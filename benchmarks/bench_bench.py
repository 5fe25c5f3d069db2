"""Thrust bench: session overhead, fit accuracy against Table 2, valve-closing latencies.

Emulators run in this process on ptys (realistic balance: 0.3 s lag, 0.2 g noise,
10 Hz printing, drift, unstable and garbage lines); the session runs as the
installed ``tpods bench characterize`` in a subprocess, as a user runs it.
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
from bench.fit import fit_steps, max_error_pct_full_scale
from bench.session import read_session
from benchmarks.host import Window
from common.thrust_table import ThrustTable

EXE = str(Path(sys.executable).with_name("tpods"))


def _bench(seed: int = 0, **kw):
    ev = EmulatedValveController(4)
    es = EmulatedScout(ev, seed=seed, **kw)
    return ev, es, serve_pty(ev), serve_pty(es)


def _session(out: Path, vs, ss, *args: str) -> subprocess.Popen:
    return subprocess.Popen([EXE, "bench", "characterize", "--valves", vs.path, "--scale", ss.path,
                             "--out", str(out), "--no-progress", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _full_session(tmp: Path) -> list[dict]:
    ev, es, vs, ss = _bench(seed=4)
    w = Window()
    try:
        # settle = 5 lag time constants (0.3 s): shorter settles bias the means low
        p = _session(tmp / "full", vs, ss, "--dwell", "2", "--settle", "1.5", "--zero-settle", "1.5",
                     "--zero-dwell", "0.5", "--zero-every", "9")
        _, err = p.communicate(timeout=600)
        if p.returncode != 0:
            raise RuntimeError(err)
    finally:
        ss.stop()
        vs.stop()
    w.stop()
    meta = json.loads((tmp / "full" / "run.json").read_text())
    t = meta["timing"]
    _, steps = read_session(tmp / "full")
    table = fit_steps(steps).table()
    errs = max_error_pct_full_scale(table, ThrustTable.default(), np.arange(10.0, 90.01, 0.5))
    rows = [
        {"case": "bench session 4x9 steps", "metric": "overhead beyond dwell+settle (%)",
         "value": t["overhead_pct"], "reference": 5.0, "ratio": 5.0 / max(t["overhead_pct"], 1e-3),
         "ok": t["overhead_pct"] < 5.0, "target": f"< 5 % of {t['planned_s']:.0f} s planned",
         **w.timed()},
        {"case": "bench session 4x9 steps", "metric": "loop overhead, setup excluded (%)",
         "value": t["loop_overhead_pct"], "reference": 5.0,
         "ratio": 5.0 / max(t["loop_overhead_pct"], 1e-3), "ok": t["loop_overhead_pct"] < 5.0,
         "target": "< 5 %", **w.timed()},
    ]
    for k, e in errs.items():
        rows.append({"case": f"bench fit {k} nozzle(s)", "metric": "max |fit - Table 2| (% FS)",
                     "value": e, "reference": 1.0, "ratio": 1.0 / max(e, 1e-6), "ok": e < 1.0,
                     "target": "< 1 % of full scale, duty 10-90 %"})
    return rows


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
    from bench.ohaus import OhausScout
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
        rows = _full_session(tmp)
        rows += _capture_rows(tmp)
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
