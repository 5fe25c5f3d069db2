"""A valve dead time, tested: the profile likelihood of a delay between
the commands and the thrust.

The commands are shifted later by each delay of a grid (:func:`shift_commands`: valves
closed until the first shifted command), the model re-fitted at each (warm-started from the
fit without delay), and the cost ``chi2(d) = sum r^T W r`` (``-2 log L`` up to a constant,
the noise as stated) profiled. The best delay is refined by a parabola through the grid's
lowest point and its neighbours (then refined); its sigma is where the profile rises by 1,
its 95 % interval where it rises by 3.84 (clipped to the grid: a delay is not negative); the
likelihood-ratio statistic ``LR = chi2(0) - chi2(best)`` is compared with chi-square(1)
(p-value). When the residuals are larger than the stated noise the profile is first divided
by the reduced chi-square at the best delay (a quasi-likelihood: the interval widens, LR
shrinks). A delay the run does not inform gives a flat profile and a wide interval.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from common.chi2 import sf as chi2_sf
from common.errors import UserError

DEFAULT_DELAYS_S = tuple(np.round(np.arange(0.0, 0.1001, 0.01), 4))
"""The default grid, s: 0 to 100 ms by 10 ms."""

REFINE_S = 0.002
"""Half-width of the first refining parabola around the grid's best delay, s."""

REFINE_STEPS = 4

Z95 = 1.959964
"""Half-width of the 95 % interval in sigmas (the profile rising by 3.84)."""

LR_ALPHA = 0.01
"""A delay is reported as found when its LR test rejects 'no delay' at this level."""


def shift_commands(cmd_t: np.ndarray, rows: np.ndarray, delay_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Commands (times (Nc,), rows (Nc, C)) taking effect ``delay_s`` later: a closed row
    (zeros) holds from the first time until the first shifted command."""
    cmd_t = np.asarray(cmd_t, float)
    rows = np.asarray(rows, float)
    if delay_s == 0:
        return cmd_t, rows
    if delay_s < 0:
        raise UserError(f"a valve delay must be >= 0 s, got {delay_s:g}")
    return (np.concatenate([cmd_t[:1], cmd_t + delay_s]),
            np.vstack([np.zeros((1,) + rows.shape[1:]), rows]))


@dataclass
class DelayScan:
    """The profile of a valve dead time.

    Attributes:
        delays_s, cost: every delay evaluated (the grid and the refinement) and ``chi2``
            at each (as fitted, noise as stated).
        best_s: the minimiser (parabolic refinement), s; ``sigma_s`` its standard
            deviation (the profile's curvature); ``interval_s`` its 95 % interval.
        lr: ``(chi2(0) - chi2(best)) / scale``; ``p_value`` of it under chi-square(1).
        scale: the reduced chi-square at the best delay when above 1 (else 1).
        n_obs, n_params: residuals and fitted parameters (for the reduced chi-square).
    """

    delays_s: np.ndarray
    cost: np.ndarray
    best_s: float
    sigma_s: float
    interval_s: tuple[float, float]
    lr: float
    p_value: float
    scale: float
    n_obs: int
    n_params: int

    @property
    def found(self) -> bool:
        """True when 'no delay' is rejected at :data:`LR_ALPHA`."""
        return self.p_value < LR_ALPHA

    def describe(self) -> str:
        lo, hi = self.interval_s
        return (f"valve dead time {1e3 * self.best_s:.1f} +- {1e3 * self.sigma_s:.2g} ms (95 % interval "
                f"{1e3 * lo:.1f}..{1e3 * hi:.1f} ms); likelihood ratio against none "
                f"{self.lr:.3g} (chi-square(1) p = {self.p_value:.2g})"
                + ("" if self.scale == 1 else f", after dividing by the reduced chi-square "
                   f"{self.scale:.3g}"))

    def to_dict(self) -> dict[str, object]:
        return {"delays_s": self.delays_s.tolist(), "cost": self.cost.tolist(),
                "best_s": self.best_s, "sigma_s": self.sigma_s,
                "interval_s": list(self.interval_s), "lr": self.lr,
                "p_value": self.p_value, "scale": self.scale, "found": self.found,
                "n_obs": self.n_obs, "n_params": self.n_params}


def profile(cost_at: Callable[[float], float], delays_s: Sequence[float], n_obs: int,
            n_params: int) -> DelayScan:
    """:class:`DelayScan` of ``cost_at(delay)`` (``chi2``, non-finite for a failed fit) over
    the grid ``delays_s`` (sorted, starting at 0), the best refined by up to
    :data:`REFINE_STEPS` parabolas through ``best +- h`` (``h`` from :data:`REFINE_S`,
    shrinking with the steps): the profile is not quadratic over a grid spacing."""
    d = np.asarray(sorted(float(x) for x in delays_s))
    if len(d) < 3 or d[0] != 0.0:
        raise UserError("a delay scan needs at least 3 delays, the first 0")
    seen: dict[float, float] = {}

    def at(x: float) -> float:
        x = round(float(x), 9)
        if x not in seen:
            seen[x] = float(cost_at(x))
        return seen[x]

    c = np.array([at(x) for x in d])
    ok = np.isfinite(c)
    if not ok[0] or ok.sum() < 3:
        raise UserError("the delay scan failed: the fit without delay (or most shifted fits) "
                        "did not give a finite cost")
    i = int(np.argmin(np.where(ok, c, np.inf)))
    best, curv = _parabola(d, c, i, ok)
    c_best = float(c[i])
    h = REFINE_S
    for _ in range(REFINE_STEPS if curv > 0 else 0):
        xs = np.unique(np.clip([best - h, best, best + h], 0.0, float(d[-1])))
        cs = np.array([at(x) for x in xs])
        if len(xs) < 3 or not np.all(np.isfinite(cs)):
            break
        a, b, c0 = np.polyfit(xs, cs, 2)
        if a <= 0:
            break
        new = float(np.clip(-b / (2 * a), max(xs[0] - h, 0.0), xs[-1] + h))
        moved, best, curv = abs(new - best), new, float(a)
        c_best = min(float(cs.min()), float(np.polyval((a, b, c0), best)))
        if moved < 0.25 / math.sqrt(a):  # a quarter of the (unscaled) interval
            break
        h = max(min(h, 2 * moved), REFINE_S / 4)
    grid = np.array(sorted(seen))
    cost = np.array([seen[x] for x in grid])
    c_best = min(c_best, float(np.nanmin(np.where(np.isfinite(cost), cost, np.nan))))
    scale = max(1.0, c_best / max(n_obs - n_params - 1, 1))
    sigma = math.inf if curv <= 0 else math.sqrt(scale / curv)
    half = Z95 * sigma
    lo, hi = max(best - half, 0.0), min(best + half, float(d[-1]))
    lr = max(float(c[0]) - c_best, 0.0) / scale
    return DelayScan(grid, cost, best, sigma, (lo, hi), lr, float(chi2_sf(lr, 1)), scale, n_obs,
                     n_params)


def _parabola(d, c, i, ok) -> tuple[float, float]:
    """Minimiser and curvature ``a`` (cost ~ a (x - best)^2 + c0) through the lowest grid
    point and its neighbours; at an end of the grid, the end (curvature from the side)."""
    j = [k for k in (i - 1, i, i + 1) if 0 <= k < len(d) and ok[k]]
    if len(j) < 3:
        j = sorted(np.argsort(np.where(ok, np.abs(d - d[i]), np.inf))[:3])
    a, b, _ = np.polyfit(d[j], c[j], 2)
    if a <= 0:
        return float(d[i]), 0.0
    x = float(np.clip(-b / (2 * a), d[0], d[-1]))
    return x, float(a)


def batch_delay_scan(pose_t, pose, cmd_t, thrust_n, fit, *, sigma_pos_m: float,
                     sigma_yaw_rad: float, delays_s: Sequence[float] = DEFAULT_DELAYS_S,
                     max_iter: int = 30) -> DelayScan:
    """:func:`profile` of a batch least-squares fit ``fit`` (a
    :class:`estimator.batch.ls_result.BatchResult` of these poses and thrusts, held
    ``(cmd_t, thrust_n)``): every delay re-fits the same unknowns (the fixed parameters as
    in ``fit``, no prior) from ``fit``'s estimate, over the whole span at once."""
    from estimator.batch.least_squares import batch_ls

    w = np.array([sigma_pos_m, sigma_pos_m, sigma_yaw_rad]) ** -2
    fixed = {k: v for k, v in fit.params.items() if k not in fit.names}

    def cost_at(delay: float) -> float:
        if delay == 0:
            res = fit.residuals
        else:
            ct, th = shift_commands(cmd_t, thrust_n, delay)
            try:
                res = batch_ls(pose_t, pose, ct, th, names=fit.names, fixed=fixed,
                               initial=fit.z0, sigma_pos_m=sigma_pos_m,
                               sigma_yaw_rad=sigma_yaw_rad, max_iter=max_iter,
                               horizon0_s=None, tol=1e-6).residuals
            except UserError:
                return math.inf
        return float(np.sum(np.asarray(res) ** 2 * w))

    return profile(cost_at, delays_s, 3 * len(pose_t), len(fit.z0))


def delay_warning(scan: DelayScan) -> str:
    """The warning line of a delay the scan found ('' when 'no delay' stands)."""
    if not scan.found:
        return ""
    return (f"the run shows a {scan.describe()}: the thrust starts and stops later than the "
            "commands. Give the delay to the model (a vehicle file's [valves] delay_s) or shift "
            "the commands; a shared supply or damping does not improve the fit this way")


def run_delay_scan(run, table, fit, *, clamp: bool = False, sigma_pos_m: float,
                   sigma_yaw_rad: float, delays_s: Sequence[float] = DEFAULT_DELAYS_S) -> DelayScan:
    """:func:`batch_delay_scan` on a :class:`common.runfolder.Run` (as fitted: the window
    applied) with its thrusts from ``table`` (a structure's virtual thrusts; thrusts.csv
    shifted the same way)."""
    cmd_t, thrust = run.thrust_profile(table, clamp=clamp)
    return batch_delay_scan(run.pose_t, run.pose, cmd_t, thrust, fit, sigma_pos_m=sigma_pos_m,
                            sigma_yaw_rad=sigma_yaw_rad, delays_s=delays_s)
