"""How much a run's sample intervals jitter, against what a stated frame rate allows.

A mocap system or a control loop with a stated rate delivers its samples at that rate to
well under a percent; a log whose intervals spread by tens of percent (a Windows timer's
1/64 s steps, a loop that sleeps "about" its period) was not timed by its stated rate, and
a fit on its nominal clock mis-scales every rate and acceleration. Pure function on times.
"""

from __future__ import annotations

import numpy as np

SPREAD_LIMIT = 1.10
"""p95/p5 of the intervals above which they jitter far beyond a stated frame rate."""
REL_STD_LIMIT = 0.05
"""std/median of the intervals above which they do."""


def interval_jitter(t: np.ndarray) -> dict:
    """The spread of the positive intervals of times ``t`` (s): ``n``, ``median_s``,
    ``p5_s``, ``p95_s``, ``spread`` (p95/p5), ``rel_std`` (std/median) and ``large`` (either
    beyond :data:`SPREAD_LIMIT` / :data:`REL_STD_LIMIT`); ``large`` False with fewer than
    two positive intervals (nothing to judge)."""
    t = np.asarray(t, float)
    dt = np.diff(t[np.isfinite(t)])
    dt = dt[dt > 0]
    if len(dt) < 2:
        return {"n": int(len(dt)), "median_s": float(dt[0]) if len(dt) else None, "p5_s": None,
                "p95_s": None, "spread": None, "rel_std": None, "large": False}
    p5, med, p95 = (float(x) for x in np.percentile(dt, [5, 50, 95]))
    spread = p95 / p5
    rel_std = float(np.std(dt) / med)
    return {"n": int(len(dt)), "median_s": med, "p5_s": p5, "p95_s": p95, "spread": spread,
            "rel_std": rel_std, "large": bool(spread > SPREAD_LIMIT or rel_std > REL_STD_LIMIT)}


def jitter_warning(j: dict) -> str | None:
    """One line saying how far the intervals jitter, or None when they do not."""
    if not j["large"]:
        return None
    return (f"the pose intervals jitter far beyond a stated frame rate: 5-95 % "
            f"{1e3 * j['p5_s']:.1f}-{1e3 * j['p95_s']:.1f} ms around the median {1e3 * j['median_s']:.1f} ms "
            f"(p95/p5 {j['spread']:.2f}, std/median {100 * j['rel_std']:.0f} %); a clock at a stated rate "
            f"holds its intervals within about 1 %")


OFF_GRID_LIMIT = 0.2
"""5-95 % span of the intervals' distance from a whole number of median periods above which
a run's times jitter (dropped frames leave whole multiples: no jitter)."""


def off_grid_span(t: np.ndarray) -> float:
    """The 5-95 % span of ``dt / median - round(dt / median)`` over the positive intervals of
    ``t``: 0 for a steady clock with dropped frames, tens of percent for a coarse or busy one
    (0 with fewer than two intervals)."""
    t = np.asarray(t, float)
    dt = np.diff(t[np.isfinite(t)])
    dt = dt[dt > 0]
    if len(dt) < 2:
        return 0.0
    q = dt / np.median(dt)
    r = q - np.round(q)
    p5, p95 = np.percentile(r, [5, 95])
    return float(p95 - p5)
