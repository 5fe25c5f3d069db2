"""Pose times rebuilt from a log's own finite-difference velocities, or from an interval column.

Some labs log a nominal control clock (a fixed step per row) beside velocities computed as
finite differences of the poses over the TRUE interval: ``v_k = (p_k - p_{k-1}) / dt_k``.
Then ``dt_k = (p_k - p_{k-1}) / v_k`` for any component that moved. Per row:

- each of x, y and yaw gives ``dt`` with a relative error bound from the logged resolution
  of its cells (``q_p / |dp| + q_v / |v|``, half a quantum each); a component whose bound
  is at most :data:`MAX_REL` resolves the interval, the best resolved one gives it;
- resolved components that disagree beyond their bounds (and :data:`AGREE_REL`) mean the
  velocities of that row are not finite differences of these positions (a filter, another
  source): the row is not used;
- a row that nothing resolves (at rest, or an empty/NaN cell), that disagrees, or whose
  interval comes out non-positive or non-finite takes the median of the determined ones.

The first row keeps its nominal time. Pure functions on arrays; no files are read here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MAX_REL = 0.02
"""Largest relative error bound (from the cells' resolution) of a component that resolves."""
AGREE_REL = 1e-6
"""Relative disagreement allowed between resolved components beyond their bounds."""

DETERMINED, REST, MISSING, DISAGREE, REJECTED = range(5)
STATUS = ("determined", "at_rest", "missing", "disagree", "rejected")


@dataclass
class Intervals:
    """``dt`` (N-1,) seconds between consecutive rows, every one positive and finite, and
    ``status`` (N-1,): :data:`DETERMINED` or why it was filled with ``fill_s``."""

    dt: np.ndarray
    status: np.ndarray
    fill_s: float
    method: str

    def counts(self) -> dict[str, int]:
        """How many intervals have each status (``determined``, ``at_rest``, ...)."""
        return {name: int((self.status == i).sum()) for i, name in enumerate(STATUS)}


def _filled(dt: np.ndarray, status: np.ndarray, method: str) -> Intervals:
    ok = status == DETERMINED
    if not ok.any():
        raise ValueError("no row determines its interval")
    fill = float(np.median(dt[ok]))
    return Intervals(np.where(ok, dt, fill), status, fill, method)


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Angles (rad) wrapped to (-pi, pi]."""
    return np.angle(np.exp(1j * np.asarray(a, float)))


def intervals_from_velocities(pos: np.ndarray, vel: np.ndarray, quantum_pos: np.ndarray | None = None,
                              quantum_vel: np.ndarray | None = None) -> Intervals:
    """The intervals of rows whose positions ``pos`` (N, 3: x, y in one length unit, yaw in
    rad; a column of NaN for a component not logged) were differentiated into ``vel``
    (N, 3, per second). ``quantum_*`` (N, 3): the logged resolution of each cell (default:
    exact float64 numbers). A :class:`ValueError` when no row's interval is determined."""
    pos = np.asarray(pos, float)
    vel = np.asarray(vel, float)
    qp = np.abs(np.spacing(np.nan_to_num(pos))) if quantum_pos is None else np.asarray(quantum_pos, float)
    qv = np.abs(np.spacing(np.nan_to_num(vel))) if quantum_vel is None else np.asarray(quantum_vel, float)
    d = np.diff(pos, axis=0)
    d[:, 2] = wrap_angle(d[:, 2])
    v = vel[1:]
    with np.errstate(invalid="ignore", divide="ignore"):
        r = d / v
        err = 0.5 * (qp[1:] + qp[:-1]) / np.abs(d) + 0.5 * qv[1:] / np.abs(v)
    finite = np.isfinite(r) & np.isfinite(err)
    err = np.where(finite, err, np.inf)
    resolved = err <= MAX_REL
    rows = np.arange(len(d))
    best = np.argmin(err, axis=1)
    dt = r[rows, best]
    e_best = err[rows, best]
    with np.errstate(invalid="ignore"):
        gap = np.abs(r - dt[:, None]) > (AGREE_REL + 2.0 * (err + e_best[:, None])) * np.abs(dt[:, None])
    status = np.full(len(d), DETERMINED, np.int8)
    status[~resolved.any(axis=1)] = REST
    status[~resolved.any(axis=1) & ~np.isfinite(np.column_stack([d, v])).all(axis=1)] = MISSING
    has = resolved.any(axis=1)
    status[has & (resolved & gap).any(axis=1)] = DISAGREE
    status[(status == DETERMINED) & ~(np.isfinite(dt) & (dt > 0))] = REJECTED
    if not (status == DETERMINED).any():
        if (status == DISAGREE).any():
            raise ValueError(f"the components give different intervals in every row that moves "
                             f"({int((status == DISAGREE).sum())}): the velocity columns are not finite "
                             "differences of these positions")
        raise ValueError("no row's velocity determines its interval (the body never moves, or "
                         "the velocity columns are not finite differences of the positions)")
    return _filled(dt, status, "velocities")


def intervals_from_column(dt: np.ndarray) -> Intervals:
    """The intervals of a logged interval column (N,): row k's cell is the time since row
    k-1 (the first row's cell is not used); an empty or NaN cell, or a non-positive one,
    takes the median of the others."""
    d = np.asarray(dt, float)[1:]
    status = np.full(len(d), DETERMINED, np.int8)
    status[~np.isfinite(d)] = MISSING
    with np.errstate(invalid="ignore"):
        status[np.isfinite(d) & (d <= 0)] = REJECTED
    if not (status == DETERMINED).any():
        raise ValueError("no positive interval in the column")
    return _filled(d, status, "interval-column")


def rebuilt_times(t_nominal: np.ndarray, pos: np.ndarray, vel: np.ndarray) -> np.ndarray:
    """(N,) pose times: the first nominal time, then the intervals rebuilt from the velocities."""
    return times_from(t_nominal, intervals_from_velocities(pos, vel))


def times_from(t_nominal: np.ndarray, iv: Intervals) -> np.ndarray:
    """(N,) times: the first nominal time, then the cumulated intervals."""
    return float(np.asarray(t_nominal, float)[0]) + np.concatenate([[0.0], np.cumsum(iv.dt)])


def map_times(t: np.ndarray, knots_nominal: np.ndarray, knots_rebuilt: np.ndarray) -> tuple[np.ndarray, int]:
    """Nominal times ``t`` on the rebuilt clock: exact at the knots (rows of the same file),
    linear between them; beyond the ends at the overall rate. Returns ``(times, outside)``."""
    t = np.asarray(t, float)
    kn, kr = np.asarray(knots_nominal, float), np.asarray(knots_rebuilt, float)
    keep = np.concatenate([[True], np.diff(kn) > 0])  # strictly increasing knots
    kn, kr = kn[keep], kr[keep]
    out = np.interp(t, kn, kr)
    rate = (kr[-1] - kr[0]) / (kn[-1] - kn[0]) if len(kn) > 1 and kn[-1] > kn[0] else 1.0
    lo, hi = t < kn[0], t > kn[-1]
    out[lo] = kr[0] + (t[lo] - kn[0]) * rate
    out[hi] = kr[-1] + (t[hi] - kn[-1]) * rate
    return out, int(lo.sum() + hi.sum())


def summary(t_nominal: np.ndarray, t: np.ndarray, iv: Intervals, column: str) -> dict:
    """What run.json keeps of a rebuilt time base (spans, rate, counts, interval percentiles)."""
    t_nominal = np.asarray(t_nominal, float)
    nominal = float(t_nominal[-1] - t_nominal[0])
    span = float(t[-1] - t[0])
    det = iv.dt[iv.status == DETERMINED]
    p = np.percentile(det, [0, 5, 50, 95, 100])
    counts = iv.counts()
    return {"method": iv.method, "nominal_column": column, "intervals": len(iv.dt),
            "determined": counts.pop("determined"), "filled": {k: n for k, n in counts.items() if n},
            "fill_s": iv.fill_s, "nominal_span_s": nominal, "rebuilt_span_s": span,
            "rate_difference": span / nominal - 1.0 if nominal > 0 else None,
            "mean_interval_s": float(np.mean(iv.dt)),
            "determined_interval_s": dict(zip(("min", "p5", "median", "p95", "max"), map(float, p), strict=True))}


_WHY = {"at_rest": "at rest", "missing": "with an empty cell", "disagree": "where x, y and yaw disagree",
        "rejected": "non-positive"}


def describe(s: dict) -> str:
    """One line for the import's output from :func:`summary`'s dict."""
    what = "the logged velocities" if s["method"] == "velocities" else "the interval column"
    n_fill = sum(s["filled"].values())
    fill = ""
    if n_fill:
        why = ", ".join(f"{n} {_WHY[k]}" for k, n in s["filled"].items())
        fill = f"; {n_fill} filled with the median {1e3 * s['fill_s']:.1f} ms: {why}"
    rate = f" ({100 * s['rate_difference']:+.1f} %)" if s["rate_difference"] is not None else ""
    return (f"pose times rebuilt from {what} ({s['determined']} of {s['intervals']} intervals{fill}): "
            f"{s['rebuilt_span_s']:.1f} s against the nominal {s['nominal_span_s']:.1f} s of "
            f"{s['nominal_column']}{rate}, intervals {1e3 * s['determined_interval_s']['min']:.0f}-"
            f"{1e3 * s['determined_interval_s']['max']:.0f} ms, mean {1e3 * s['mean_interval_s']:.1f} ms")
