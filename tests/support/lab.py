"""Shared helpers of the live tests: loopback Zenoh peers, a whole simulated lab in-process."""

from __future__ import annotations

import time
from contextlib import contextmanager

from common.thrust_table import ThrustTable
from common.zenoh_net import open_session
from estimator.plant.model import PlantParams
from tests.support.net import free_port, matching, wait_for
from tpods.clock import LabClock
from tpods.plant_loop import SimulatedModule
from tpods.player import cmd_key

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


def switch_lag_ms(module, play_dir) -> tuple[float, float]:
    """(mean, largest) gap in lab ms between a valve change the simulated module applied
    and the player's stamp of the command that asked for it (same duties, nearest in time).

    A fraction of a millisecond on a machine that keeps up with the time scale; on one
    too loaded, the emulated controller reads its commands late (tens to hundreds of ms),
    the module's physics no longer match the commands recorded, and no estimator can be
    judged on the run. The mean is what biases an estimate (the impulse misplaced)."""
    import json

    import numpy as np
    import pandas as pd

    meta = json.loads((play_dir / "run.json").read_text())
    df = pd.read_csv(play_dir / "commands.csv")
    t_cmd = df["t"].to_numpy() + meta["t0_lab"]
    duties = df.drop(columns="t").to_numpy()
    lags = []
    for t_s, d in module.plant.switches:
        same = np.all(np.isclose(duties, d), axis=1)
        if same.any():
            lags.append(float(np.min(np.abs(t_cmd[same] - t_s))))
    lags = 1e3 * np.asarray(lags)
    return float(lags.mean()), float(lags.max())


def run_lab_procs(out, exe: str, *, duration_s: float = 24.0, scale: float = 2.0,
                  method: str = "ls-ekf", extra_live: tuple[str, ...] = (), seed: int = 0):
    """Like :func:`run_lab` with the estimator and the player as the real commands
    (subprocesses, as in the lab and the demo); the module stays in this process.

    Returns ``(summary, play_meta, module)``.
    """
    import json
    import subprocess

    table = ThrustTable.default()
    with loopback_peers(1) as (ep, (a,)):
        clock = LabClock(scale, time.time())
        zargs = ["--connect", ep, "--no-multicast"]
        with SimulatedModule(a, TRUTH, table, clock=clock, seed=seed) as module:
            live = subprocess.Popen([exe, "estimate", "live", "--method", method, "--out",
                                     str(out / "live"), "--exit-on-end", "--json", "--quiet",
                                     *extra_live, *zargs],
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            try:
                probe = a.declare_publisher(cmd_key("tpods1"))
                assert wait_for(lambda: matching(probe) or live.poll() is not None, 60.0)
                probe.undeclare()
                assert live.poll() is None, live.stderr.read()
                time.sleep(0.3)
                play_p = subprocess.run(
                    [exe, "run", "play", "--valves", module.valves_path, "--input", "phase-sine",
                     "--duration", f"{duration_s:g}", "--out", str(out / "play"),
                     "--time-scale", f"{scale:g}", "--clock-origin", repr(clock.origin),
                     "--no-progress", *zargs], capture_output=True, text=True, timeout=300)
                assert play_p.returncode == 0, play_p.stderr
                stdout, stderr = live.communicate(timeout=120)
            finally:
                if live.poll() is None:
                    live.kill()
            assert live.returncode == 0, stderr
    summary = json.loads(stdout.strip().splitlines()[-1])
    return summary, json.loads((out / "play" / "run.json").read_text()), module
