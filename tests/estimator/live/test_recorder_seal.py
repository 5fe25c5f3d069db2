"""The live recorder seals its data at the end of the stream, before the estimator's final
fit (:meth:`LiveRecorder.seal`): poses.csv and commands.csv are then whole and closed and
run.json says ``data_complete`` while the status is still ``running``, so a reader takes the
folder as whole and a post-processing fit can start beside the final fit (tpods demo)."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from common.runfolder import partial_status, read_run
from common.thrust_table import ThrustTable
from estimator.live.runtime import LiveConfig, LiveEstimator, LiveRecorder
from estimator.plant.inputs import phase_sine
from estimator.plant.model import PlantParams
from estimator.plant.sim import SimConfig, simulate

T0 = 1.763e9


@pytest.fixture(scope="module")
def sim():
    cmd_t, duty = phase_sine(12.0, 50.0)
    return simulate(cmd_t, duty, PlantParams(2.5, 4.2e-3), config=SimConfig(seed=5))


def _feed_all_but_the_end(est, sim, n_cmds: int) -> None:
    """The first ``n_cmds`` commands and every pose they cover (the rest of the poses too:
    a stream whose last command is older than its last poses)."""
    ct, d = sim.cmd_t, sim.duty_pct
    ci = 0
    for k, t in enumerate(sim.pose_t):
        while ci < n_cmds and ct[ci] <= t:
            est.command({"t": T0 + ct[ci], "duty": list(d[ci])})
            ci += 1
        est.pose({"body": "tpods1", "frame": k + 1, "t": T0 + t, "x": sim.pose[k][0],
                  "y": sim.pose[k][1], "yaw": sim.pose[k][2], "occluded": False}, T0 + t)
        est.process(T0 + t + 0.01)


def test_the_seal_closes_whole_data_files_and_readers_take_them_as_whole(sim, tmp_path, capsys):
    d = tmp_path / "run"
    rec = LiveRecorder(d, {"kind": "live-estimate"})
    est = LiveEstimator(ThrustTable.default(), LiveConfig(), recorder=rec)
    n_cmds = len(sim.cmd_t) - 5  # the last poses are newer than the last command
    _feed_all_but_the_end(est, sim, n_cmds)
    seen = {}

    def final_fit():  # what a reader sees while the estimator computes its final fit
        seen["meta"] = json.loads((d / "run.json").read_text())
        seen["run"] = read_run(d)
        seen["stderr"] = capsys.readouterr().err

    est.final_thrust_part = final_fit
    est.finish()
    meta = seen["meta"]
    assert meta["status"] == "running" and meta["data_complete"] is True
    assert seen["stderr"] == ""  # not warned about as a partial run
    assert partial_status(meta) is None
    run = seen["run"]
    # every pose the filter took is in, the last ones covered by the closing hold row
    assert len(run.pose_t) == est.counters.updates == meta["recorded"]["poses"]
    assert np.allclose(run.pose, sim.pose[:len(run.pose_t)], atol=1e-10)
    assert run.cmd_t[-1] == pytest.approx(run.pose_t[-1], abs=1e-9)
    assert meta["recorded"]["commands"] == n_cmds + 1  # + the closing hold row
    # after the seal nothing more is recorded; the estimates file stays open until close
    rec.command(T0 + 1e3, [10, 10, 10, 10])
    rec.pose(T0 + 1e3, 0.0, 0.0, 0.0)
    rec.close("success", {"final": est.summary()})
    after = read_run(d)
    assert np.array_equal(after.pose_t, run.pose_t) and np.array_equal(after.cmd_t, run.cmd_t)
    final = json.loads((d / "run.json").read_text())
    assert final["status"] == "success" and final["recorded"]["commands_unrecorded"] == 1
    assert len(pd.read_csv(d / "estimates.csv")) == est.counters.updates


@pytest.mark.parametrize("meta,partial", [
    ({"status": "running", "data_complete": True}, None),
    ({"status": "running"}, "running"),
    ({"status": "running", "data_complete": "yes"}, "running"),
    ({"status": "aborted", "data_complete": True}, "aborted"),
    ({"status": "success", "data_complete": True}, None),
])
def test_only_a_sealed_running_recording_reads_as_whole(meta, partial):
    assert partial_status(meta) == partial
