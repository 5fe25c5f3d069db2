"""Bench helpers: fast emulators (short lag, fast printing) served on ptys by the test
process, and reading a session's results. The ``bench`` fixture is in tests/conftest.py."""

from __future__ import annotations

import json
import os
import subprocess
import time
from pathlib import Path

import pandas as pd

from bench.emulators import EmulatedScout, EmulatedValveController, serve_pty
from bench.ohaus.driver import parse_weight_line


class Bench:
    def __init__(self, seed: int = 7, scale_baud: float | None = None, **scout_kw) -> None:
        self.valves = EmulatedValveController(4)
        kw = dict(lag_s=0.02, print_rate_hz=100, seed=seed)
        kw.update(scout_kw)
        self.scout = EmulatedScout(self.valves, **kw)
        self.vsrv = serve_pty(self.valves)
        self.ssrv = serve_pty(self.scout, baud=scale_baud)

    @property
    def paths(self) -> tuple[str, str]:
        return self.vsrv.path, self.ssrv.path

    def stop(self) -> None:
        self.ssrv.stop()
        self.vsrv.stop()

    def sent_weights(self, before: float = float("inf")):
        """(value, stable) of every weight line the balance sent before ``before``."""
        out = []
        for s in self.scout.sent:
            if s.kind == "weight" and s.t < before:
                r = parse_weight_line(s.data)
                out.append((r.value, r.stable))
        return out

    def state_at(self, t: float) -> tuple[float, ...]:
        st = self.valves.log[0].duties
        for ch in self.valves.log:
            if ch.t <= t:
                st = ch.duties
        return st

    def first_change_after(self, t: float):
        return next((c for c in self.valves.log if c.t > t), None)


def recorded(raw_csv: Path):
    raw = pd.read_csv(raw_csv)
    return [(round(v, 2), bool(s)) for v, s in zip(raw["reading_gf"], raw["stable"], strict=True)]


def start_session(exe: str, bench: Bench, out: Path, *extra: str) -> subprocess.Popen:
    v, s = bench.paths
    args = [exe, "bench", "characterize", "--valves", v, "--scale", s, "--out", str(out),
            "--no-progress", *extra]
    return subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "MPLBACKEND": "Agg"})


def wait_open(bench: Bench, proc: subprocess.Popen, timeout: float = 20.0) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if any(bench.valves.duties):
            return
        if proc.poll() is not None:
            raise AssertionError(f"session ended early: {proc.communicate()}")
        time.sleep(0.005)
    raise AssertionError("the valves never opened")


def run_json(out: Path) -> dict:
    return json.loads((out / "run.json").read_text())
