"""Shared helpers of the live tests: loopback Zenoh peers, a whole simulated lab in-process."""

from __future__ import annotations

import threading
import time
from contextlib import contextmanager

from bench.thrust_table import ThrustTable
from bench.valves import ValveController
from estimator.inputs import phase_sine
from estimator.live import LiveConfig, LiveEstimator, LiveRecorder, run_live
from estimator.model import PlantParams
from mocap_bridge.zenoh_net import open_session
from tests.mocap.conftest import free_port, matching, wait_for
from tpods.clock import LabClock
from tpods.plant_loop import SimulatedModule
from tpods.player import cmd_key, play

TRUTH = PlantParams(2.268, 3.78e-3)


@contextmanager
def loopback_peers(n: int = 2):
    """``n`` in-process peers: the first listens on a free loopback port, the others connect."""
    ep = f"tcp/127.0.0.1:{free_port()}"
    sessions = [open_session(listen=[ep], no_multicast=True)]
    sessions += [open_session(connect=[ep], no_multicast=True) for _ in range(n - 1)]
    try:
        assert wait_for(lambda: len(sessions[0].info.peers_zid()) >= n - 1, 10.0)
        yield ep, sessions
    finally:
        for s in reversed(sessions):
            s.close()


def run_lab(out, *, duration_s: float = 25.0, scale: float = 8.0, method: str = "ls-ekf",
            ls_window_s: float = 10.0, ls_start: str = "handoff", params: PlantParams = TRUTH, seed: int = 0,
            est_table=None, noise=None):
    """Player -> emulated valves (pty) -> plant -> bridge -> Zenoh -> live estimator.

    Returns ``(summary, play_result, module)``; the estimator's run folder is ``out/live``,
    the player's ``out/play``.
    """
    table = ThrustTable.default()
    with loopback_peers(2) as (_ep, (a, b)):
        clock = LabClock(scale, time.time())
        cfg = LiveConfig(method=method, ls_window_s=ls_window_s, ls_start=ls_start)
        rec = LiveRecorder(out / "live", {"kind": "live-estimate", "test": True})
        est = LiveEstimator(est_table or table, cfg, "tpods1", recorder=rec)
        box: dict = {}
        stop = threading.Event()
        t = threading.Thread(target=lambda: box.update(r=run_live(b, est, stop=stop,
                                                                  exit_on_end=True)),
                             daemon=True)
        t.start()
        with SimulatedModule(a, params, table, clock=clock, seed=seed, noise=noise) as module:
            pub = a.declare_publisher(cmd_key("tpods1"))
            probe = a.declare_publisher("tpods/mocap/tpods1/pose")
            assert wait_for(lambda: matching(probe), 10.0)
            probe.undeclare()
            cmd_t, duty = phase_sine(duration_s, 50.0)
            with ValveController(module.valves_path) as vc:
                res = play(vc, cmd_t, duty, clock=clock, publish=pub.put, out_dir=out / "play")
            t.join(timeout=30.0)
            stop.set()
            t.join(timeout=10.0)
        rec.close(box["r"].status if "r" in box else "failed", {"final": est.summary()})
    return est.summary(), res, module
