"""The player announcing its schedule ahead: each command published before it is due,
stamped with when it is due, so a live estimator fed the same run never re-runs a pose;
a run stopped early restates the rows it announced but never played as closed."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from bench.emulators import EmulatedValveController, serve_pty
from bench.valves import ValveController
from common.thrust_table import ThrustTable
from estimator.live.core import LiveConfig, LiveEstimator
from estimator.plant.inputs import phase_sine
from tpods.clock import LabClock
from tpods.player import decode_command, play

AHEAD_S = 0.05


@pytest.fixture
def valves():
    emu = EmulatedValveController(4)
    srv = serve_pty(emu)
    try:
        yield emu, srv.path
    finally:
        srv.stop()


def _play(path, cmd_t, duty, ahead_s: float = AHEAD_S, **kw):
    clock = LabClock()
    sent: list[tuple[float, dict]] = []  # (lab time published, message)
    with ValveController(path) as vc:
        res = play(vc, cmd_t, duty, clock=clock, lead_s=0.05, announce_ahead_s=ahead_s,
                   publish=lambda b: sent.append((clock.now(), decode_command(b))), **kw)
    return res, sent


def test_commands_go_out_ahead_stamped_when_due_and_the_estimator_never_rewinds(valves):
    _, path = valves
    cmd_t, duty = phase_sine(0.6, 20.0)
    res, sent = _play(path, cmd_t, duty)
    assert res.status == "success"
    sets = [(tp, m) for tp, m in sent if m["kind"] != "hold"]
    assert len(sets) == len(cmd_t) and sets[-1][1]["kind"] == "end"
    due = res.t_start + (cmd_t - cmd_t[0])
    assert np.array_equal([m["t"] for _, m in sets], due)  # stamped when due, exactly
    assert all(tp <= m["t"] - AHEAD_S + 0.02 for tp, m in sets)  # and published ahead
    # the valves switched at (about) those times: commands.csv keeps the measured stamps
    measured = np.array([t for t, _ in res.sent[:len(cmd_t)]])
    assert np.all((measured >= due) & (measured - due < 0.05))

    # a live estimator fed the run (poses at 1 kHz, each on arrival) never re-runs one
    est = LiveEstimator(ThrustTable.default(), LiveConfig(method="ekf", publish_rate_hz=0))
    pose_t = np.arange(due[0] + 5e-4, due[-1], 1e-3)
    events = [(tp, 1, m) for tp, m in sent]
    events += [(t, 0, {"body": "tpods1", "frame": k + 1, "t": t, "x": 0.0, "y": 0.0,
                       "yaw": 0.0, "occluded": False}) for k, t in enumerate(pose_t)]
    events.sort(key=lambda e: (e[0], -e[1]))
    for arr, kind, m in events:
        if kind:
            est.command(m, arr)
        else:
            est.pose(m, arr)
        est.process(arr)
    c = est.summary()["counters"]
    assert c["updates"] == len(pose_t) and c["rewinds"] == 0 and c["align_cmds_rewound"] == 0


def test_a_stopped_run_restates_the_rows_it_never_played_as_closed(valves):
    emu, path = valves
    cmd_t, duty = phase_sine(2.0, 20.0)
    stop = threading.Event()
    threading.Timer(0.4, stop.set).start()
    res, sent = _play(path, cmd_t, duty, ahead_s=0.5, stop=stop)
    assert res.status == "aborted" and not any(emu.duties)
    msgs = [m for _, m in sent]
    assert msgs[-1]["kind"] == "end" and not any(msgs[-1]["duty"])
    last = {}
    for m in msgs:
        if m["kind"] != "hold":
            last[m["t"]] = m["duty"]  # the same stamp: the later message wins
    after = [d for t, d in last.items() if t > msgs[-1]["t"]]
    assert len(after) >= 5 and not any(any(d) for d in after)  # announced, not played: closed
    assert len(res.sent) < len(cmd_t)  # stopped before the end of the schedule
