"""The time line of a zero-order hold: segments between pose times and command switches.

Commands (thrusts or duties) hold from each switch time to the next; the estimators and
the simulator integrate segment by segment, never across a switch. These helpers split the
time line (:func:`zoh_segments`) and give each segment its held thrust (:func:`segment_thrust`).
"""

from __future__ import annotations

import numpy as np


def zoh_segments(cmd_t: np.ndarray, t_nodes: np.ndarray):
    """Split ``[t_nodes[0], t_nodes[-1]]`` at every node and every command switch.

    Args:
        cmd_t: (Nc,) increasing switch times; row j holds on [cmd_t[j], cmd_t[j+1]).
        t_nodes: (N,) non-decreasing times that must be segment boundaries (poses).

    Returns:
        ``(events, cmd_idx, node_pos)``: (M,) boundary times, (M-1,) index of the
        command row active on each segment (-1 before the first command: zero
        thrust), and (N,) position of each node in ``events``.
    """
    cmd_t = np.asarray(cmd_t, dtype=float)
    t_nodes = np.asarray(t_nodes, dtype=float)
    inner = cmd_t[(cmd_t > t_nodes[0]) & (cmd_t < t_nodes[-1])]
    events = np.union1d(t_nodes, inner)
    cmd_idx = np.searchsorted(cmd_t, events[:-1], side="right") - 1
    node_pos = np.searchsorted(events, t_nodes)
    return events, cmd_idx, node_pos


def segment_thrust(thrust_n: np.ndarray, cmd_idx: np.ndarray) -> np.ndarray:
    """(M-1, 4) thrust on each segment (zero before the first command)."""
    thrust_n = np.asarray(thrust_n, dtype=float)
    out = thrust_n[np.clip(cmd_idx, 0, None)]
    out[cmd_idx < 0] = 0.0
    return out
