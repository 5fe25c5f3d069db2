"""``--resume``: a live estimator continues from the run folder of one that died; the
time it was down is a named gap, and no pose is counted twice."""

from __future__ import annotations

import csv
import functools
import json
import subprocess
import sys

from common.thrust_table import ThrustTable
from estimator.live.core import LiveEstimator
from estimator.live.recorder import LiveRecorder
from estimator.live.resume import resume_from
from tests.support.sim import sim_run

RUN = sim_run(2.268, 3.78e-3, 5, duration=16.0)


def _feed(est, t_from: float, t_to: float) -> None:
    """The simulated run's messages stamped in [t_from, t_to) as a live stream."""
    events = sorted([(t, 1, i) for i, t in enumerate(RUN.cmd_t)]
                    + [(t, 0, i) for i, t in enumerate(RUN.pose_t)])
    for t, kind, i in events:
        if not t_from <= t < t_to:
            continue
        if kind:
            est.command({"body": "tpods1", "t": float(t), "duty": list(RUN.duty_pct[i]),
                         "kind": "set", "seq": i + 1}, float(t))
        else:
            x, y, psi = RUN.pose[i]
            est.pose({"body": "tpods1", "frame": i + 1, "t": float(t), "x": x, "y": y,
                      "yaw": psi, "occluded": False}, float(t))
        est.process(float(t) + 1e-3)


def _times(folder) -> list[float]:
    t0 = json.loads((folder / "run.json").read_text())["t0_lab"]
    with (folder / "poses.csv").open() as fh:
        return [t0 + float(r["t"]) for r in csv.DictReader(fh)]


def _dead_then_resumed(tmp_path, restart_at: float):
    """A live estimator fed up to 8 s, killed; a new one resumed from its folder and fed
    the stream again from ``restart_at``. Returns (full run's summary, new estimator,
    the dead folder's pose times, the new folder's)."""
    table = ThrustTable.default()
    dead = LiveEstimator(table, recorder=LiveRecorder(tmp_path / "a", {"kind": "live-estimate"}))
    _feed(dead, -1.0, 8.0)  # then killed: its folder stays "running"
    dead.recorder._pose.close()  # (what the OS does for a killed process's files)
    dead.recorder._cmd.close()
    rec = LiveRecorder(tmp_path / "b", {"kind": "live-estimate"})
    new = LiveEstimator(table, recorder=rec)
    r = resume_from(new, tmp_path / "a")
    assert r["replayed_poses"] > 900 and r["dead_run_status"] == "running"
    _feed(new, restart_at, 99.0)
    new.finish()
    rec.close("success", {"final": new.summary()})
    return _full(), new, _times(tmp_path / "a"), _times(tmp_path / "b")


@functools.cache
def _full() -> dict:
    """The same run with no interruption (its summary)."""
    full = LiveEstimator(ThrustTable.default())
    _feed(full, -1.0, 99.0)
    full.finish()
    return full.summary()


def test_resume_counts_no_pose_twice(tmp_path):
    """The stream comes again from 7.7 s (0.3 s the dead one had recorded): those poses
    are refused, every pose is in the new folder once, the estimate is the full run's."""
    full, new, a, b = _dead_then_resumed(tmp_path, 7.7)
    assert b[:len(a)] == a  # the dead run's poses, once each
    assert all(y > x for x, y in zip(b, b[1:], strict=False))  # none twice
    assert new.aligner.stats.too_old > 0  # the overlap refused
    assert len(b) == len([t for t in RUN.pose_t if t >= RUN.cmd_t[0]])
    s = new.summary()
    assert abs(s["mass_kg"] - full["mass_kg"]) < 0.1 * s["mass_sigma_kg"]


def test_resume_names_the_time_it_was_down(tmp_path):
    """Down from 8 s to 9 s: the poses and commands of that second are a named gap, the
    input over it unknown; the estimate stays within 3 sigma of the full run's."""
    full, new, a, b = _dead_then_resumed(tmp_path, 9.0)
    assert b[:len(a)] == a and all(y > x for x, y in zip(b, b[1:], strict=False))
    s = new.summary()
    streams = {g["stream"]: g for g in s["gaps"]}
    assert set(streams) == {"poses", "commands"}
    assert 90 < streams["poses"]["missing"] < 150  # ~1 s at 120 Hz
    assert s["counters"]["motion_resets"] >= 1
    assert abs(s["mass_kg"] - full["mass_kg"]) < 3 * s["mass_sigma_kg"]
    assert abs(s["izz_kgm2"] - full["izz_kgm2"]) < 3 * s["izz_sigma_kgm2"]


def test_resume_refusals_are_one_line(tmp_path):
    (tmp_path / "empty").mkdir()
    exe = [sys.executable, "-m", "tpods.cli", "estimate", "live", "--no-multicast",
           "--listen", "tcp/127.0.0.1:0"]
    p = subprocess.run([*exe, "--resume", str(tmp_path / "empty"), "--out", str(tmp_path / "o")],
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == 2 and "not a live run folder to resume" in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1, p.stderr
    p = subprocess.run([*exe, "--resume", str(tmp_path / "o2"), "--out", str(tmp_path / "o2")],
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == 2 and "another --out folder" in p.stderr, p.stderr
