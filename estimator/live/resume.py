"""Resume the live estimator from the run folder of one that died (``tpods estimate live
--resume RUN_DIR``).

:func:`resume_from` reads the folder's commands.csv and poses.csv (times from its
``t0_lab``) and feeds them to a new :class:`~estimator.live.core.LiveEstimator` in time
order, as if they had just arrived: the filter is where the dead one was at its last
recorded pose, and the new run folder (``--out``, another folder) holds them again, so it
is a whole run by itself. Then the live stream continues:

- no pose is counted twice: the aligner refuses a pose not newer than the last one it
  released (``too_old``), so a pose the dead process had already recorded is not used again;
- the time the estimator was down is a gap: the first live pose and the first live command
  after it are named (``missing`` estimated from the recorded rates), and the input over
  it is unknown (the filter forgets the motion there, as across lost commands).

Replayed poses get frame numbers -1, -2, ... (the folder keeps no frame numbers): they can
never be taken for the live mocap's.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import Any

from common.errors import UserError


def _rows(path: Path) -> list[list[float]]:
    try:
        with path.open() as fh:
            r = csv.reader(fh)
            next(r, None)
            return [[float(x) for x in row] for row in r if row]
    except (OSError, ValueError) as exc:
        raise UserError(f"{path}: cannot read it to resume ({exc})") from None


def resume_from(est: Any, run_dir: str | Path) -> dict[str, Any]:
    """Feed the recorded commands and poses of ``run_dir`` to ``est`` (see the module
    notes); returns what was replayed (counts, last times, the dead run's status)."""
    run = Path(run_dir)
    try:
        meta = json.loads((run / "run.json").read_text())
    except (OSError, ValueError) as exc:
        raise UserError(f"{run}: not a live run folder to resume (run.json: {exc})") from None
    t0 = meta.get("t0_lab")
    cmds = _rows(run / "commands.csv") if (run / "commands.csv").exists() else []
    poses = _rows(run / "poses.csv") if (run / "poses.csv").exists() else []
    if t0 is None or not cmds:
        raise UserError(f"{run}: holds no command yet; nothing to resume from (start afresh)")
    events = sorted([(t0 + c[0], 1, i) for i, c in enumerate(cmds)]
                    + [(t0 + p[0], 0, i) for i, p in enumerate(poses)])
    for t, kind, i in events:
        if kind:
            est.command({"body": est.body, "t": t, "duty": cmds[i][1:], "kind": "set"}, t)
        else:
            _, x, y, psi = poses[i]
            est.aligner.push_pose(-(i + 1), t, x, y, psi, arrival=t)
            est.counters.poses_rx += 1
    est.process(math.inf)
    t_pose = t0 + poses[-1][0] if poses else None
    t_cmd = t0 + cmds[-1][0]
    est.gaps.resumed(t_pose, _period(poses), t_cmd, _period(cmds))
    return {"resumed_from": str(run), "replayed_commands": len(cmds),
            "replayed_poses": len(poses), "t_last_pose_lab": t_pose, "t_last_cmd_lab": t_cmd,
            "dead_run_status": meta.get("status")}


def _period(rows: list[list[float]]) -> float:
    """Median spacing of the rows' times (s; 0.01 when fewer than two)."""
    t = sorted(r[0] for r in rows)
    d = sorted(b - a for a, b in zip(t, t[1:], strict=False) if b > a)
    return d[len(d) // 2] if d else 0.01
