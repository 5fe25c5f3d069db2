"""A flight across the hosts of a lab of namespaces (:mod:`tests.support.lab_net`).

- router host: ``tpods net router`` (eclipse-zenoh, router mode) on ``tcp/10.77.0.1:7447``;
- module host: :mod:`tests.support.lab_module` (the valve emulator on ``socket://`` and the
  simulated module, poses as Vicon UDP over the camera link);
- mocap host: ``tpods mocap bridge --source vicon-udp`` (Zenoh client of the router);
- estimator host: ``tpods estimate live --out`` and ``tpods run play --valves socket://...``
  (both Zenoh clients of the router).

:class:`LabFlight` starts them, lets a test inject faults while the player plays, and
collects what each side kept (:class:`FlightResult`). Every process runs at real time.
"""

from __future__ import annotations

import csv
import json
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tests.support.lab_net import CAMERA_ADDR, LAN_ADDR, LabNet, project_env

VALVES_PORT = 7700
MOCAP_UDP_PORT = 51001


def tpods_argv(*args: str) -> list[str]:
    """``tpods ARGS`` run from this checkout (the installed script's interpreter)."""
    exe = Path(sys.executable).with_name("tpods")
    if exe.exists():
        return [str(exe), *args]
    found = shutil.which("tpods")
    return [found, *args] if found else [sys.executable, "-m", "tpods.cli", *args]


@dataclass
class FlightResult:
    """What the hosts kept: the estimator's summary and run folder, the player's run.json,
    the module's emitted poses and valve changes, each process's stderr."""

    summary: dict[str, Any]
    live_dir: Path
    play: dict[str, Any]
    module: dict[str, Any]
    stderr: dict[str, str] = field(default_factory=dict)
    returncodes: dict[str, int | None] = field(default_factory=dict)
    events: list[tuple[float, str]] = field(default_factory=list)
    relays: dict[str, dict[str, int]] = field(default_factory=dict)

    def gaps(self) -> list[dict[str, Any]]:
        """Every gap the estimator named, from its gaps.csv (the summary lists the first
        100), in the summary's form."""
        path = self.live_dir / "gaps.csv"
        if not path.exists():
            return []
        with path.open() as fh:
            return [{"stream": g["stream"], "t_start": float(g["t_start"]),
                     "t_end": float(g["t_end"]), "duration_s": float(g["duration_s"]),
                     "missing": int(g["missing"]), "silent_s": float(g["silent_s"]),
                     "before": int(g["frame_before"]), "after": int(g["frame_after"]),
                     "host_end": float(g["host_end"])} for g in csv.DictReader(fh)]


class LabFlight:
    """The processes of one flight in ``lab`` (see the module notes)."""

    def __init__(self, lab: LabNet, out: Path, *, seed: int = 0, method: str = "ekf",
                 client_opts: tuple[str, ...] = ()) -> None:
        self.lab = lab
        self.out = Path(out)
        self.out.mkdir(parents=True, exist_ok=True)
        self.seed = seed
        self.method = method
        self.env = project_env()
        self.procs: dict[str, subprocess.Popen] = {}
        self.zargs = ["--connect", lab.router_ep, "--no-multicast", "--zenoh-mode", "client",
                      *client_opts]
        self._err: dict[str, Any] = {}

    # ------------------------------------------------------------------ processes
    def _spawn(self, name: str, host: str, argv: list[str], stdout=subprocess.DEVNULL):
        err = open(self.out / f"{name}.stderr", "w")  # noqa: SIM115 - closed in collect()
        self._err[name] = err
        p = self.lab.spawn(host, argv, stdout=stdout, stderr=err, env=self.env,
                           text=True)
        self.procs[name] = p
        return p

    def start_router(self, name: str = "router") -> subprocess.Popen:
        p = self._spawn(name, "router", tpods_argv(
            "net", "router", "--listen", self.lab.router_ep, "--no-multicast"),
            stdout=subprocess.PIPE)
        line = p.stdout.readline()
        if "listening on" not in line:
            raise RuntimeError(f"the router did not start: {line!r}")
        return p

    def restart_router(self, down_s: float) -> float:
        """Stop the router (SIGTERM), wait ``down_s`` seconds, start it again; the wall
        time its new process started."""
        self.lab.events.append((time.time(), "router stopped"))
        self.lab.stop(self.procs["router"])
        time.sleep(down_s)
        t = time.time()
        self.start_router("router2")
        self.lab.events.append((t, "router started"))
        return t

    def start_module(self) -> None:
        p = self._spawn("module", "module", [
            sys.executable, "-m", "tests.support.lab_module",
            "--valves-listen", f"{LAN_ADDR['module']}:{VALVES_PORT}",
            "--mocap-udp", f"{CAMERA_ADDR['mocap']}:{MOCAP_UDP_PORT}",
            "--seed", str(self.seed), "--out", str(self.out / "module.json")],
            stdout=subprocess.PIPE)
        line = p.stdout.readline()
        if not line.startswith("ready"):
            raise RuntimeError(f"the module host did not start: {line!r}")

    def start_bridge(self, connect: str | None = None, bind: str | None = None,
                     port: int = MOCAP_UDP_PORT, extra: tuple[str, ...] = ()) -> None:
        """The bridge on the mocap host; ``connect``: another Zenoh endpoint than the
        router's (a relay's), ``bind``/``port``: where it takes the Vicon datagrams;
        ``extra``: more options."""
        zargs = list(self.zargs)
        if connect is not None:
            zargs[1] = connect
        self._spawn("bridge", "mocap", tpods_argv(
            "mocap", "bridge", "--source", f"vicon-udp:{port}",
            "--bind", bind or CAMERA_ADDR["mocap"], *extra, *zargs))

    def start_relay(self, host: str, kind: str, listen: str, upstream: str,
                    delay_ms: float = 50.0, jitter_ms: float = 20.0) -> subprocess.Popen:
        """:mod:`tests.support.delay_relay` in ``host``'s namespace."""
        p = self._spawn(f"relay-{kind}", host, [
            sys.executable, "-m", "tests.support.delay_relay", kind, listen, upstream,
            "--delay-ms", f"{delay_ms:g}", "--jitter-ms", f"{jitter_ms:g}",
            "--seed", str(self.seed)], stdout=subprocess.PIPE)
        line = p.stdout.readline()
        if not line.startswith("ready"):
            raise RuntimeError(f"the relay did not start: {line!r}")
        return p

    def start_estimator(self, name: str = "live", out: str = "live",
                        extra: tuple[str, ...] = ()) -> subprocess.Popen:
        return self._spawn(name, "estimator", tpods_argv(
            "estimate", "live", "--method", self.method, "--out", str(self.out / out),
            "--exit-on-end", "--json", "--quiet", *extra, *self.zargs), stdout=subprocess.PIPE)

    def start_player(self, duration_s: float, watchdog_ms: int = 500) -> subprocess.Popen:
        return self._spawn("play", "estimator", tpods_argv(
            "run", "play", "--valves", f"socket://{LAN_ADDR['module']}:{VALVES_PORT}",
            "--input", "phase-sine", "--duration", f"{duration_s:g}",
            "--out", str(self.out / "play"), "--no-progress", "--wait-subscriber", "20",
            "--watchdog-ms", str(watchdog_ms), *self.zargs))

    def start_all(self, duration_s: float, bridge: dict[str, Any] | None = None) -> float:
        """Router, module, bridge (``bridge``: :meth:`start_bridge`'s options), estimator,
        then the player; the wall time the player started."""
        self.start_router()
        self.start_module()
        self.start_bridge(**(bridge or {}))
        self.start_estimator()
        self.start_player(duration_s)
        return time.time()

    # ------------------------------------------------------------------ results
    def wait(self, name: str, timeout_s: float) -> int | None:
        try:
            return self.procs[name].wait(timeout_s)
        except subprocess.TimeoutExpired:
            return None

    def collect(self, live: str = "live", timeout_s: float = 60.0) -> FlightResult:
        """Wait for the player and the estimator, stop the rest, read what each kept."""
        rc: dict[str, int | None] = {}
        rc["play"] = self.wait("play", timeout_s)
        out_live = ""
        p = self.procs[live]
        try:
            out_live, _ = p.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.lab.stop(p)
        rc[live] = p.returncode
        for name in ("bridge", "module", "router2", "router"):
            if name in self.procs:
                rc[name] = self.lab.stop(self.procs[name])
        relays = {}
        for name in [n for n in self.procs if n.startswith("relay")]:
            self.lab.stop(self.procs[name])
            last = (self.procs[name].stdout.read() or "").strip().splitlines()
            relays[name] = json.loads(last[-1]) if last else {}
        for f in self._err.values():
            f.close()
        stderr = {n: (self.out / f"{n}.stderr").read_text() for n in self._err}
        lines = [x for x in (out_live or "").strip().splitlines() if x.startswith("{")]
        summary = json.loads(lines[-1]) if lines else {}
        play_json = self.out / "play" / "run.json"
        module_json = self.out / "module.json"
        return FlightResult(
            summary=summary, live_dir=self.out / live,
            play=json.loads(play_json.read_text()) if play_json.exists() else {},
            module=json.loads(module_json.read_text()) if module_json.exists() else {},
            stderr=stderr, returncodes=rc, events=list(self.lab.events), relays=relays)
