"""Revised live estimates, as a consumer sees them, and the batch filter they equal.

The live estimator updates on each pose as it arrives, with the commands it has. A command
that arrives after poses it governs makes it re-run them (:mod:`estimator.live.history`) and
publish their estimates again with ``rev`` counting the re-runs and ``revised`` true. A
consumer keeps, per pose (its ``frame``), the estimate of the highest ``rev``
(:func:`latest_per_frame`); once every command is in, those equal the batch EKF run over the
same poses and commands (:func:`batch_reference`, :func:`max_rel_diff`), pose by pose.

:func:`arrival_order` builds such a stream from arrays (poses on time, commands late by
given delays) for the tests and the bench; pure functions, no network, no clock.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from estimator.filters.config import PAPER, STATE_NAMES, EkfConfig
from estimator.filters.loop import run_ekf
from estimator.filters.result import EkfResult


def latest_per_frame(messages: Iterable[Mapping[str, Any]]) -> dict[int, Mapping[str, Any]]:
    """Frame -> the estimate message of the highest revision (``rev``, absent: 0; a tie:
    the later message). Messages without an integer ``frame`` are skipped."""
    out: dict[int, Mapping[str, Any]] = {}
    for m in messages:
        f = m.get("frame")
        if not isinstance(f, int):
            continue
        old = out.get(f)
        if old is None or m.get("rev", 0) >= old.get("rev", 0):
            out[f] = m
    return out


def batch_reference(pose_t, pose, cmd_t, thrust_n, cfg: EkfConfig = PAPER) -> EkfResult:
    """The batch EKF (:func:`estimator.filters.loop.run_ekf`) over poses ``pose_t`` (N,)
    s, ``pose`` (N, 3) (x, y m, yaw rad) and commands ``cmd_t`` (Nc,) s, ``thrust_n`` (Nc, 4)
    N, started as the live filter starts: the setting's state with the first pose's x, y,
    yaw, the setting's covariance."""
    x0 = np.array(cfg.x0, dtype=float)
    x0[:3] = np.asarray(pose, dtype=float)[0]
    return run_ekf(pose_t, pose, cmd_t, thrust_n, cfg, x0=x0)


def estimate_vector(m: Mapping[str, Any]) -> np.ndarray:
    """An estimate message's filter state as the batch filter's 8 states (x, y, psi, u, v,
    r, mass, Izz)."""
    st = m["state"]
    return np.array([*(st[k] for k in STATE_NAMES[:6]), m["mass_kg"], m["izz_kgm2"]], dtype=float)


def max_rel_diff(latest: Mapping[int, Mapping[str, Any]], frames: np.ndarray,
                 ref: EkfResult) -> float:
    """Largest difference between the estimates of ``latest`` (:func:`latest_per_frame`)
    and the batch filter ``ref`` whose row ``k`` is the pose of frame ``frames[k]``, each
    state relative to ``max(1, |batch|)`` (inf when a frame has no estimate)."""
    worst = 0.0
    for k, f in enumerate(np.asarray(frames).tolist()):
        m = latest.get(int(f))
        if m is None:
            return math.inf
        b = ref.x[k]
        d = np.abs(estimate_vector(m) - b) / np.maximum(1.0, np.abs(b))
        worst = max(worst, float(np.max(d)))
    return worst


def arrival_order(pose_t, cmd_t, cmd_delay_s) -> list[tuple[float, int, int]]:
    """The stream a live estimator receives when pose ``k`` arrives at its time
    ``pose_t[k]`` and command ``i`` at ``cmd_t[i] + cmd_delay_s[i]`` (s): ``(arrival s,
    kind 0 pose / 1 command, index)`` sorted by arrival (a tie: the command first)."""
    arrive = np.asarray(cmd_t, float) + np.asarray(cmd_delay_s, float)
    ev = [(float(t), 1, i) for i, t in enumerate(arrive)]
    ev += [(float(t), 0, k) for k, t in enumerate(np.asarray(pose_t, float))]
    ev.sort(key=lambda e: (e[0], -e[1], e[2]))
    return ev
