"""Update at once, correct if late: commands that arrive up to 5 ms late and out of order
make the live filter re-run the poses they govern and publish those estimates again,
revised; after the revisions every pose's estimate equals the batch filter's over the same
data. Pure arrays in, no network, no clock."""

from __future__ import annotations

import numpy as np
import pytest

from common.thrust_table import ThrustTable
from common.wire import decode_estimate
from estimator.filters.config import PAPER
from estimator.live.core import LiveConfig, LiveEstimator
from estimator.live.revisions import (
    arrival_order,
    batch_reference,
    estimate_vector,
    latest_per_frame,
    max_rel_diff,
)
from estimator.plant.inputs import phase_sine
from estimator.plant.model import PlantParams
from estimator.plant.sim import SimConfig, simulate

T0 = 1.763e9
TABLE = ThrustTable.default()


@pytest.fixture(scope="module")
def run():
    """3 s at 1 kHz; commands at 250 Hz (4 ms apart) and holds (the duty in force again)
    every 0.1 s, each after the first late by 0 to 5 ms: some arrive after later ones."""
    cmd_t, duty = phase_sine(3.0, 250.0)
    sim = simulate(cmd_t, duty, PlantParams(2.5, 4.2e-3),
                   config=SimConfig(pose_rate_hz=1000.0, seed=11))
    holds = np.arange(0.05, 3.0, 0.1)
    ih = np.searchsorted(sim.cmd_t, holds, "right") - 1
    ct = np.concatenate([sim.cmd_t, holds])
    cd = np.vstack([sim.duty_pct, sim.duty_pct[ih]])
    kind = ["set"] * len(sim.cmd_t) + ["hold"] * len(holds)
    delay = np.random.default_rng(5).uniform(0.0, 0.005, len(ct))
    delay[0] = 0.0  # the first command before the first pose: no pose is dropped
    return sim, ct, cd, kind, delay


def _feed(est: LiveEstimator, sim, ct, cd, kind, delay, payloads: bool = False) -> None:
    for arr, what, i in arrival_order(sim.pose_t + T0, ct + T0, delay):
        if what == 1:
            est.command({"body": "tpods1", "t": T0 + ct[i], "duty": list(cd[i]),
                         "kind": kind[i]}, arr)
        else:
            x, y, yaw = sim.pose[i]
            est.pose({"body": "tpods1", "frame": i + 1, "t": T0 + sim.pose_t[i], "x": x,
                      "y": y, "yaw": yaw, "occluded": False}, arr)
        est.process(arr)
    est.finish()


def test_late_and_out_of_order_commands_end_at_the_batch_filter_pose_by_pose(run):
    sim, ct, cd, kind, delay = run
    arrive = ct + delay
    order = np.argsort(arrive, kind="stable")
    assert np.any(np.diff(ct[order]) < 0)  # the stream has commands out of order
    msgs: list[dict] = []
    est = LiveEstimator(TABLE, LiveConfig(method="ekf", publish_rate_hz=0, max_wait_s=0.0))
    est.publish_bytes = lambda b: msgs.append(decode_estimate(b))
    _feed(est, sim, ct, cd, kind, delay)
    c = est.summary()["counters"]
    n = len(sim.pose_t)
    assert c["updates"] == n and c["align_before_first_cmd"] == 0  # every pose used at once
    assert c["align_cmds_late"] == 0 and c["rewinds"] > 100
    # a hold repeats the duty in force: no rewind, unless it overtook the set before it
    n_holds = kind.count("hold")
    assert n_holds - 5 <= c["cmds_no_change"] <= n_holds
    assert c["revised_published"] == c["rewind_updates"] > 0

    latest = latest_per_frame(msgs)
    assert sorted(latest) == list(range(1, n + 1))
    revised = [m for m in msgs if m["revised"]]
    assert revised and all(m["rev"] > 0 for m in revised)
    assert all(m["rev"] == 0 and not m["revised"] for m in msgs if not m["revised"])

    thrust = TABLE.thrust_n(cd[np.argsort(ct, kind="stable")], clamp=True)
    ref = batch_reference(sim.pose_t + T0, sim.pose, np.sort(ct) + T0, thrust, PAPER)
    frames = np.arange(1, n + 1)
    assert max_rel_diff(latest, frames, ref) <= 1e-12
    # the noise sigmas of the history too
    hist = np.asarray(est.history)
    np.testing.assert_allclose(hist[:, 1], ref.x[:, 6], rtol=1e-12)
    np.testing.assert_allclose(hist[:, 2], ref.sigma[:, 6], rtol=1e-12)
    np.testing.assert_allclose(hist[:, 4], ref.sigma[:, 7], rtol=1e-12)

    # the first estimates of the revised poses were off: the revisions corrected them
    first = {}
    for m in msgs:
        first.setdefault(m["frame"], m)
    off = [f for f, m in latest.items() if m["rev"] > 0
           and np.max(np.abs(estimate_vector(first[f]) - ref.x[f - 1])) > 1e-9]
    assert len(off) > 100


def test_a_run_whose_commands_are_all_on_time_never_revises(run):
    sim, ct, cd, kind, _ = run
    msgs: list[dict] = []
    est = LiveEstimator(TABLE, LiveConfig(method="ekf", publish_rate_hz=0))
    est.publish = msgs.append
    _feed(est, sim, ct, cd, kind, np.zeros(len(ct)))
    c = est.summary()["counters"]
    assert c["rewinds"] == 0 and c["revised_published"] == 0
    assert c["updates"] == len(sim.pose_t)
    assert {m["rev"] for m in msgs} == {0}


def test_old_estimate_payloads_read_as_first_estimates():
    old = (b'{"schema":"tpods.estimate/1","body":"a","seq":1,"t":1.0,"frame":3,"t_pub":1.0,'
           b'"mass_kg":2.0}')
    d = decode_estimate(old)
    assert d["rev"] == 0 and d["revised"] is False
    latest = latest_per_frame([d, {**d, "rev": 2, "mass_kg": 2.5}, {**d, "rev": 1}])
    assert latest[3]["mass_kg"] == 2.5
