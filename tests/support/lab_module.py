"""The module host of a lab of namespaces (``python -m tests.support.lab_module``): an
emulated valve controller served on TCP (``socket://HOST:PORT``, as a module's Wi-Fi serial
bridge), the simulated module following it, and its poses sent as Vicon Tracker UDP
datagrams to the mocap host (over the camera link).

It prints ``ready`` once it serves, runs until SIGTERM or SIGINT, then writes ``--out``
(JSON): poses emitted (first and last frame, lab times), every valve change (monotonic and
wall time, duties, cause: ``command``, ``watchdog``), the connections the valve server saw.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
import time

from bench.emulators import EmulatedValveController
from bench.emulators.tcp import TcpServer
from common.thrust_table import ThrustTable
from estimator.plant.model import PlantParams
from tpods.plant_loop import PlantLoop, udp_sink


def _addr(text: str) -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    return host, int(port)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="lab_module")
    ap.add_argument("--valves-listen", required=True, metavar="HOST:PORT")
    ap.add_argument("--mocap-udp", required=True, metavar="HOST:PORT")
    ap.add_argument("--pose-rate", type=float, default=100.0, help="lab Hz")
    ap.add_argument("--mass", type=float, default=2.268)
    ap.add_argument("--izz", type=float, default=3.78e-3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", required=True, metavar="FILE.json")
    ap.add_argument("--trust", action="append", default=None, metavar="ADDR",
                    help="the only addresses the valve link answers (repeatable; default any)")
    a = ap.parse_args(argv)
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    sys.setswitchinterval(2e-4)  # the emulated controller answers within a fraction of a ms
    valves = EmulatedValveController(4)
    wall_minus_mono = time.time() - time.monotonic()
    plant = PlantLoop(valves, PlantParams(a.mass, a.izz), ThrustTable.default(),
                      udp_sink(_addr(a.mocap_udp)), pose_rate_hz=a.pose_rate, seed=a.seed)
    host, port = _addr(a.valves_listen)
    server = TcpServer(valves, host, port, trust=a.trust)
    plant.start()
    print(f"ready {server.url}", flush=True)
    try:
        while not stop.wait(0.1):
            if plant.error is not None:
                break
    finally:
        plant.stop()
        server.stop()
    t, _ = plant.truth_arrays()
    out = {"frames": plant.frames, "first_frame": 1, "last_frame": plant.frames,
           "t_first": float(t[0]) if len(t) else None, "t_last": float(t[-1]) if len(t) else None,
           "pose_rate_hz": a.pose_rate, "watchdog_trips": valves.watchdog_trips,
           "changes": [{"t_mono": c.t, "t_wall": c.t + wall_minus_mono, "duties": list(c.duties),
                        "cause": c.cause} for c in valves.log],
           "refused": server.refused,
           "error": None if plant.error is None else str(plant.error)}
    with open(a.out, "w") as fh:
        json.dump(out, fh)
    return 0


if __name__ == "__main__":
    sys.exit(main())
