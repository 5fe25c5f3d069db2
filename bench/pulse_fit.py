"""On/off valve pulses on a load cell: the steady force per valve and per number of valves
open together, and each valve's dead time and rise from the pulse edges. Pure functions on
the session's tables (:mod:`bench.session`, :mod:`bench.loadcell_import`); no device I/O.

**Steady force.** Each pulse is a step of the session: its dwell readings minus the zero
interpolated between the closed windows around it (``steps.csv``). A valve's force is the
mean over the pulses it fired alone; its sigma is the pulses' scatter over sqrt(n) (with
fewer than three pulses, the pulses' own standard error: the readings' standard deviation
over the square root of the number of *independent* readings, see below, and that of the
zero interpolated under the pulse, the median zero window's over sqrt(2)), plus a relative
scale error the session cannot see (the load cell's calibration), in quadrature. Per number
of valves open, the same over every pulse with that many open.

**Sample and hold.** An HX711 converts at about 10 Hz (80 Hz at most) while a logger writes
its last value on every row: runs of equal readings. The update period ``T_u`` is the median
duration of the runs; a run of rows holds one independent reading, so a step's n readings
count as ``n dt / T_u``. An edge is fitted on one sample per update: per run, at the time
the new value arrived (between the row before and the run's first row, taken at the midpoint:
unbiased, +-dt/2), and in a run longer than one update (a flat stretch, where the value did
not change) one more every ``T_u``. The update clock's phase against the valve command
is unknown and need not vary from edge to edge (a logger's rows and the commands often
share a clock): the timing floor of a delay or a rise is the rows' resolution
``dt / sqrt(12)``, and ``T_u / sqrt(12)`` for an edge faster than one update (rise < ``T_u``),
which lands between two readings; a floor is not reduced by averaging edges.

**Edges.** A first-order-plus-dead-time step, fitted (trust-region least squares with bounds,
several starting delays) to each opening edge from ``pre_s`` before the command to
``span_s`` after it::

    y(t) = y0                                                   t < t_cmd + delay
    y(t) = y0 + A (1 - exp(-(t - t_cmd - delay) / rise))         after

The same on each closing edge gives the closing delay and fall time. Per valve: the mean
over its edges, with sigma the largest of the edges' scatter over sqrt(n), the fits' own
sigma over sqrt(n) and the timing floor above. The delay and rise are
those of the whole chain (valve, tube, nozzle, load cell, amplifier and any filter in the
logger), which is what a run's thrust model needs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from common.errors import UserError
from common.thrust_table import GF_TO_N

MIN_PULSES_FOR_SCATTER = 3


@dataclass(frozen=True)
class EdgeFit:
    """One edge: command time, dead time and time constant (s) with sigmas, step size (gf)."""

    valves: tuple[int, ...]
    opening: bool
    t_command_s: float
    delay_s: float
    delay_sigma_s: float
    rise_s: float
    rise_sigma_s: float
    step_gf: float
    residual_rms_gf: float
    n_samples: int


@dataclass
class PulseFit:
    """The fit of an on/off pulse session (forces in N, times in s)."""

    valves: dict[int, dict[str, Any]]
    counts: dict[int, dict[str, Any]]
    edges: list[EdgeFit] = field(default_factory=list)
    update_period_s: float = math.nan
    row_period_s: float = math.nan
    warnings: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {"valves": {str(k): v for k, v in sorted(self.valves.items())},
                "counts": {str(k): v for k, v in sorted(self.counts.items())},
                "update_period_s": self.update_period_s, "row_period_s": self.row_period_s,
                "edges": [e.__dict__ | {"valves": list(e.valves)} for e in self.edges],
                "warnings": list(self.warnings)}


def valve_columns(raw: pd.DataFrame) -> list[str]:
    """The per-valve duty columns ``d1..dN`` of a raw table, in valve order."""
    cols = [c for c in raw.columns if c.startswith("d") and c[1:].isdigit()]
    return sorted(cols, key=lambda c: int(c[1:]))


def is_pulse_session(raw: pd.DataFrame) -> bool:
    """True for a session of on/off valves (``d1..dN`` columns holding only 0 and 100)."""
    cols = valve_columns(raw)
    if not cols:
        return False
    d = raw[cols].to_numpy(dtype=float)
    return bool(np.all(np.isin(d, (0.0, 100.0))) and np.any(d == 100.0))


def hold_runs(t_s: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Runs of equal consecutive readings: each run's first time, value and duration (to
    the next run's start; the last run's is NaN)."""
    t = np.asarray(t_s, dtype=float)
    y = np.asarray(y, dtype=float)
    first = np.r_[True, y[1:] != y[:-1]]
    ts = t[first]
    dur = np.r_[np.diff(ts), math.nan]
    return ts, y[first], dur


def update_period(t_s: np.ndarray, y: np.ndarray) -> float:
    """The amplifier's update period: the median duration of the runs of equal readings
    bounded by changes (a long flat stretch, a zero clamped at 0.00, is not counted)."""
    _, _, dur = hold_runs(t_s, y)
    dur = dur[np.isfinite(dur)]
    if dur.size == 0:
        return math.nan
    short = dur[dur <= np.percentile(dur, 75)]
    return float(np.median(short))


def fopdt_step(p: np.ndarray, t: np.ndarray, t_cmd: float) -> np.ndarray:
    """The first-order-plus-dead-time edge at times ``t``; ``p = (y0, A, delay, rise)``."""
    y0, a, d, tau = p
    x = np.maximum(t - t_cmd - d, 0.0)
    return y0 + a * (1.0 - np.exp(-x / tau))


def fit_edge(t_s: np.ndarray, y: np.ndarray, t_cmd: float, row_period_s: float,
             t_update_s: float, valves: tuple[int, ...] = (), opening: bool = True) -> EdgeFit | None:
    """First-order-plus-dead-time fit of one edge on the held readings ``y`` at row times
    ``t_s`` (already cut to the edge's window); None when the window holds too few samples."""
    from scipy.optimize import least_squares

    ts, ys, dur = hold_runs(t_s, y)
    dur[-1] = float(t_s[-1]) + row_period_s - ts[-1]
    # a run longer than one update held the same value through several updates: one sample
    # per update period in it, so that a flat stretch weighs as the updates it spans
    k = np.maximum(1, np.round(dur / t_update_s)).astype(int)
    ts = np.repeat(ts, k) + np.concatenate([np.arange(n) for n in k]) * t_update_s
    ys = np.repeat(ys, k)
    ts = np.maximum(ts - row_period_s / 2, float(t_s[0]))  # arrival between two rows
    if len(ts) < 6:
        return None
    before = ys[ts < t_cmd]
    y0 = float(np.median(before)) if before.size else float(ys[0])
    tail = ys[ts > ts[0] + 0.66 * (ts[-1] - ts[0])]
    a = float(np.median(tail)) - y0
    if a == 0:
        return None
    span = float(ts[-1] - t_cmd)
    frac = (ys - y0) / a
    after = ts >= t_cmd
    moved = np.flatnonzero(after & (frac > 0.1))
    d0 = max(0.0, float(ts[moved[0]] - t_cmd) - t_update_s) if moved.size else 0.0
    hit = np.flatnonzero(after & (frac > 0.63))
    tau0 = max(0.01, float(ts[hit[0]] - t_cmd) - d0) if hit.size else 0.1
    lo = [-np.inf, -np.inf, 0.0, 1e-3]
    hi = [np.inf, np.inf, max(span, 1e-3), max(span, 1e-2)]
    best = None
    for dd in (d0, d0 + 0.5 * t_update_s, max(0.0, d0 - 0.5 * t_update_s), d0 + t_update_s):
        p0 = np.array([y0, a, min(dd, hi[2] * 0.99), min(tau0, hi[3] * 0.99)])
        sol = least_squares(lambda p: fopdt_step(p, ts, t_cmd) - ys, p0, bounds=(lo, hi))
        if best is None or sol.cost < best.cost:
            best = sol
    r = best.fun
    dof = max(1, len(ts) - 4)
    s2 = float(r @ r) / dof
    try:
        cov = np.linalg.pinv(best.jac.T @ best.jac) * s2
    except np.linalg.LinAlgError:
        return None
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    return EdgeFit(valves, opening, float(t_cmd), float(best.x[2]), float(sd[2]), float(best.x[3]),
                   float(sd[3]), float(best.x[1]), math.sqrt(float(r @ r) / len(r)), len(ts))


def _mean_sigma(values: np.ndarray, own_sigmas: np.ndarray, floor: float) -> tuple[float, float]:
    """Mean of per-edge (or per-pulse) values and its sigma: the largest of the scatter over
    sqrt(n) (three or more values), the values' own sigmas over sqrt(n), and ``floor``."""
    n = len(values)
    own = math.sqrt(float(np.mean(own_sigmas**2)) / n) if n else math.nan
    scatter = float(np.std(values, ddof=1)) / math.sqrt(n) if n >= MIN_PULSES_FOR_SCATTER else 0.0
    return float(np.mean(values)), max(scatter, own, floor)


def _step_valves(raw: pd.DataFrame, cols: list[str]) -> dict[int, tuple[int, ...]]:
    """Each step's open valves (1-based)."""
    out = {}
    for step, g in raw[raw["step"] >= 0].groupby("step"):
        d = g[cols].iloc[0].to_numpy(dtype=float)
        out[int(step)] = tuple(int(i) + 1 for i in np.flatnonzero(d > 0))
    return out


def fit_pulses(raw: pd.DataFrame, steps: pd.DataFrame, scale_rel: float = 0.0,
               pre_s: float = 1.0, span_s: float = 3.0) -> PulseFit:
    """Steady forces, dead times and rises of an on/off pulse session (see the module)."""
    cols = valve_columns(raw)
    if not cols:
        raise UserError("the session has no per-valve columns d1..dN: not an on/off pulse session "
                        "(tpods bench import writes them)")
    raw = raw.sort_values("t_s").reset_index(drop=True)
    t = raw["t_s"].to_numpy(dtype=float)
    y = raw["reading_gf"].to_numpy(dtype=float)
    dt = float(np.median(np.diff(t))) if len(t) > 1 else math.nan
    t_u = update_period(t, y)
    t_u = max(t_u, dt) if math.isfinite(t_u) else dt
    hold = max(1.0, t_u / dt)
    warnings = []
    sets = _step_valves(raw, cols)
    st = steps.set_index("step")
    # steady force of each pulse, gf, with its own standard error (held rows are one reading)
    # the zero under each pulse is interpolated between two zero windows: their noise too
    zsem = [float(np.std(g, ddof=1)) / math.sqrt(max(1.0, len(g) / hold))
            for _, g in raw.loc[raw["phase"] == "zero"].groupby("window")["reading_gf"] if len(g) > 1]
    zero_sigma = float(np.median(zsem)) / math.sqrt(2) if zsem else 0.0
    pulses = []
    for s, v in sets.items():
        if s not in st.index or not math.isfinite(float(st.loc[s, "thrust_gf"])):
            continue
        n = float(st.loc[s, "n"])
        sd = float(st.loc[s, "std_gf"]) if math.isfinite(float(st.loc[s, "std_gf"])) else 0.0
        pulses.append((v, float(st.loc[s, "thrust_gf"]),
                       math.hypot(sd / math.sqrt(max(1.0, n / hold)), zero_sigma)))
    if not pulses:
        raise UserError("no completed pulse: no valve stayed open past the settle time")
    # edges: opening at each step's first row, closing at the first row after it
    window = raw["window"].to_numpy()
    starts = np.flatnonzero(np.r_[True, window[1:] != window[:-1]])
    edges: list[EdgeFit] = []
    for k, i0 in enumerate(starts):
        step = int(raw["step"].iloc[i0])
        prev_open = k > 0 and int(raw["step"].iloc[starts[k - 1]]) >= 0
        if step >= 0 and len(sets.get(step, ())) > 0 and not prev_open:
            v, opening = sets[step], True
        elif step < 0 and prev_open:
            v, opening = sets[int(raw["step"].iloc[starts[k - 1]])], False
        else:
            continue
        t_cmd = t[i0]
        lo_t = max(t_cmd - pre_s, t[starts[k - 1]] if k > 0 else t[0])
        hi_t = min(t_cmd + span_s, t[starts[k + 1]] if k + 1 < len(starts) else t[-1] + dt)
        sel = (t >= lo_t) & (t < hi_t)
        e = fit_edge(t[sel], y[sel], t_cmd, dt, t_u, v, opening)
        if e is not None:
            edges.append(e)
    valves: dict[int, dict[str, Any]] = {}
    for valve in sorted({x for v, _, _ in pulses for x in v}):
        alone = [(f, s) for v, f, s in pulses if v == (valve,)]
        if not alone:
            warnings.append(f"valve {valve} never fired alone: its force is in the counts only")
            continue
        f = np.array([a for a, _ in alone])
        s = np.array([b for _, b in alone])
        force, sig = _mean_sigma(f, s, 0.0)
        sig = math.hypot(sig, scale_rel * force)
        row: dict[str, Any] = {"force_n": force * GF_TO_N, "force_sigma_n": sig * GF_TO_N,
                               "force_gf": force, "n_pulses": len(alone)}
        for opening, (kd, kr) in ((True, ("delay_s", "rise_s")), (False, ("close_delay_s", "fall_s"))):
            es = [e for e in edges if e.valves == (valve,) and e.opening == opening]
            if not es:
                row.update({kd: None, f"{kd[:-2]}_sigma_s": None, kr: None, f"{kr[:-2]}_sigma_s": None})
                continue
            # an edge faster than one update lands between two readings: its timing is
            # resolved to T_u / sqrt(12) at best; a slower one is sampled along its rise
            fl = max(dt, t_u if np.median([e.rise_s for e in es]) < t_u else 0.0) / math.sqrt(12)
            d, sd = _mean_sigma(np.array([e.delay_s for e in es]),
                                np.array([e.delay_sigma_s for e in es]), fl)
            r, sr = _mean_sigma(np.array([e.rise_s for e in es]),
                                np.array([e.rise_sigma_s for e in es]), fl)
            row.update({kd: d, f"{kd[:-2]}_sigma_s": sd, kr: r, f"{kr[:-2]}_sigma_s": sr,
                        f"n_{'opening' if opening else 'closing'}_edges": len(es)})
        valves[valve] = row
    counts: dict[int, dict[str, Any]] = {}
    for k in sorted({len(v) for v, _, _ in pulses}):
        sel = [(f, s) for v, f, s in pulses if len(v) == k]
        force, sig = _mean_sigma(np.array([a for a, _ in sel]), np.array([b for _, b in sel]), 0.0)
        sig = math.hypot(sig, scale_rel * force)
        counts[k] = {"force_n": force * GF_TO_N, "force_sigma_n": sig * GF_TO_N,
                     "n_pulses": len(sel),
                     "valve_sets": sorted({",".join(map(str, v)) for v, _, _ in pulses if len(v) == k})}
    if t_u > 1.5 * dt:
        warnings.append(f"the readings are held for {hold:.1f} rows (the amplifier updates every "
                        f"{t_u * 1e3:.0f} ms): an edge faster than that is resolved to "
                        f"{t_u / math.sqrt(12) * 1e3:.0f} ms, a slower one through its rise; in the sigmas")
    if scale_rel == 0:
        warnings.append("the load cell's calibration error is not in the force sigmas "
                        "(give --scale-rel)")
    return PulseFit(valves, counts, edges, t_u, dt, warnings)
