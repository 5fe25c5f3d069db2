"""How faithfully a demo's emulated valves applied the player's commands, in the quantity an
estimate feels: the open time. Each channel's duty integrated over time (duty percent x s)
as the plant applied it (its valve changes) against the player's commands; a valve that
opened late and closed late by the same amount moves no impulse, one that closed late after
opening on time (a busy machine delaying one write) adds all of it. A calibration flight
opens each valve only a few dozen times, so one late switch can shift a factor by more than
its sigma while the mean switch lag stays small (tpods/demo_procs.switch_lag_ms).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

END_MARGIN_S = 0.5
"""The integral runs to the last command plus this, lab s (a late final close counts)."""


def _integral(t: np.ndarray, duty: np.ndarray, a: float, b: float) -> np.ndarray:
    """Per channel, the integral over [a, b] of the zero-order hold ``duty`` (N, C) that
    changes at ``t`` (N,) (0 before ``t[0]``), duty percent x s."""
    edges = np.clip(np.append(t, np.inf), a, b)
    return (np.diff(edges)[:, None] * duty).sum(axis=0)


def duty_time_error(switches: Sequence[tuple[float, Sequence[float]]], play_dir: Path
                    ) -> dict[str, float | list[float]]:
    """``{"per_channel_pct": [...], "max_abs_pct": x}``: per channel, (applied - commanded)
    / commanded duty-time in percent (NaN for a channel never commanded open), over the
    player's span; ``switches`` are the plant's valve changes ``(t_lab, duties)``,
    ``play_dir`` the player's run folder (commands.csv and run.json's ``t0_lab``)."""
    meta = json.loads((play_dir / "run.json").read_text())
    cmd = np.loadtxt(play_dir / "commands.csv", delimiter=",", skiprows=1, ndmin=2)
    t_cmd, d_cmd = cmd[:, 0] + float(meta["t0_lab"]), cmd[:, 1:]
    a, b = float(t_cmd[0]), float(t_cmd[-1]) + END_MARGIN_S
    commanded = _integral(t_cmd, d_cmd, a, b)
    if switches:
        t_sw = np.array([float(t) for t, _ in switches])
        d_sw = np.array([np.asarray(d, float) for _, d in switches]).reshape(len(t_sw), -1)
        applied = _integral(t_sw, d_sw, a, b)
    else:
        applied = np.zeros_like(commanded)
    with np.errstate(divide="ignore", invalid="ignore"):
        pct = np.where(commanded > 0, 100.0 * (applied - commanded) / commanded, np.nan)
    finite = pct[np.isfinite(pct)]
    return {"per_channel_pct": [float(x) for x in pct],
            "max_abs_pct": float(np.max(np.abs(finite))) if finite.size else 0.0}
