"""Simulated load-cell logs of on/off valve pulses, written as an HX711 logger writes them
(tests of bench.loadcell_import and bench.pulse_fit): known force per valve, dead time,
first-order rise, noise, an amplifier that updates at ``update_hz`` with a random phase and
a logger that writes the held value on every row."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def pulse_log(path: str | Path, forces_g: dict[int, float], delay_s: float, rise_s: float, *,
              pattern: tuple[tuple[int, ...], ...] = ((1,), (2,), (1,), (2,), (1, 2), (1,), (2,), (1, 2)),
              on_s: float = 4.0, off_s: float = 4.0, baseline_s: float = 3.0,
              row_hz: float = 50.0, update_hz: float = 8.3, noise_g: float = 0.15,
              resolution_g: float = 0.1, empty_rows: int = 5, seed: int = 0) -> Path:
    """Write ``t_s,weight_g,bitmask,pulse_number,phase`` (the format of
    AevarOfjord/mpc-air-bearing-satellite's logger). ``pattern``: the valves open in each
    pulse; two valves together give the sum of their forces."""
    rng = np.random.default_rng(seed)
    cmds = []  # (time, open valves)
    t = baseline_s
    for valves in pattern:
        cmds.append((t, valves))
        cmds.append((t + on_s, ()))
        t += on_s + off_s
    end = t

    def force(tt: np.ndarray) -> np.ndarray:
        f = np.zeros_like(tt)
        level = 0.0
        for tc, valves in cmds:  # each change relaxes from the current level to the new one
            target = float(sum(forces_g[v] for v in valves))
            x = np.maximum(tt - tc - delay_s, 0.0)
            after = tt >= tc + delay_s
            start = np.where(after, level, 0.0)
            f = np.where(after, start + (target - start) * (1 - np.exp(-x / rise_s)), f)
            level = target  # the pulses are long enough to settle
        return f

    period = 1.0 / update_hz
    upd = np.arange(rng.uniform(0, period), end, period)
    upd = np.sort(upd + rng.normal(0, 0.002, upd.size))  # a little clock jitter
    vals = np.round((force(upd) + rng.normal(0, noise_g, upd.size)) / resolution_g) * resolution_g
    rows = np.arange(0.0, end, 1.0 / row_hz)
    idx = np.searchsorted(upd, rows, side="right") - 1
    lines = ["t_s,weight_g,bitmask,pulse_number,phase"]
    pulse = 0
    for i, tr in enumerate(rows):
        state = ()
        for tc, valves in cmds:
            if tr >= tc:
                state = valves
        done = sum(1 for tc, v in cmds if v and tr >= tc)
        pulse = done
        mask = sum(1 << (v - 1) for v in state)
        phase = "baseline" if tr < baseline_s else ("firing" if state else "pause")
        w = "" if i < empty_rows or idx[i] < 0 else f"{vals[idx[i]]:.2f}"
        lines.append(f"{tr:.3f},{w},{mask},{pulse},{phase}")
    path = Path(path)
    path.write_text("\n".join(lines) + "\n")
    return path
