"""Polynomial thrust fits (paper Eqs. 8-11) and order selection.

Per nozzle count ``k`` the per-step mean thrusts ``z`` (gram-force) at duties ``D``
(percent) are fitted by ``h = a0 + a1 D + ... + an D^n`` in the least-squares sense,
``x = (H^T H)^-1 H^T z`` (Eq. 11; solved through a column-scaled QR/SVD, the same
estimate computed stably). For each order the result holds the residual RMS, the
coefficient covariance ``s^2 (H^T H)^-1``, AICc, BIC and the leave-one-step-out
cross-validation RMS (exact, from the hat matrix). Pure functions on arrays.

The noise variance behind a table's stated covariance (:func:`pool_noise`): a cubic on 9
duty steps leaves 5 residual degrees of freedom, and ``s^2`` from 5 is itself uncertain
(a coefficient's error over its sigma is then Student-t with 5 dof: rms 1.29, |z| > 2 in
10 % of fits instead of 5 %). The covariance is scaled by ``nu / (nu - 2)``, the variance of
Student-t with the ``nu`` residual degrees of freedom behind it, so that the stated sigma is
the rms error (and |z| > 2 in 5 % of fits again). With 2 or fewer dof per nozzle count (a
cubic on 5 steps) that variance is not finite: the counts, which share one balance and one
procedure, are then pooled (Bartlett's test of equal variances is reported; with 1 or 2 dof
per count it rejects mostly by chance, a near-zero ``s^2``, so it does not decide).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import pandas as pd

from common.chi2 import sf as chi2_sf
from common.errors import UserError
from common.thrust_table import ThrustTable

ORDERS = (1, 2, 3, 4)
CRITERIA = ("aicc", "bic", "cv")


def design_matrix(duty_pct: np.ndarray, order: int) -> np.ndarray:
    """Eq. 9: rows ``[1, D, D^2, ..., D^order]``; shape ``(q, order + 1)``."""
    d = np.asarray(duty_pct, dtype=float)
    return d[:, None] ** np.arange(order + 1)


@dataclass(frozen=True)
class PolyFit:
    """Least-squares polynomial of one order.

    Attributes:
        order: polynomial order n.
        coefficients: ``(n + 1,)`` ascending powers of duty (percent), thrust unit.
        covariance: ``(n + 1, n + 1)`` coefficient covariance ``s^2 (H^T H)^-1``
            with ``s^2 = RSS / (q - n - 1)`` (NaN when q = n + 1).
        rss: residual sum of squares; rms: ``sqrt(RSS / q)``.
        n_points: q; aicc, bic: information criteria (lower is better; AICc is
            infinite when q <= n + 2); cv_rms: leave-one-out RMS prediction error.
        residuals: ``(q,)`` data minus fit.
    """

    order: int
    coefficients: np.ndarray
    covariance: np.ndarray
    rss: float
    rms: float
    n_points: int
    aicc: float
    bic: float
    cv_rms: float
    residuals: np.ndarray = field(repr=False)

    def predict(self, duty_pct: np.ndarray | float) -> np.ndarray:
        """Fitted thrust at ``duty_pct``."""
        return np.polynomial.polynomial.polyval(np.asarray(duty_pct, dtype=float), self.coefficients)

    def criterion(self, name: str) -> float:
        return {"aicc": self.aicc, "bic": self.bic, "cv": self.cv_rms}[name]


def fit_polynomial(duty_pct: np.ndarray, thrust: np.ndarray, order: int) -> PolyFit:
    """Least-squares fit of ``thrust`` (shape ``(q,)``) against ``duty_pct`` of one order."""
    d = np.asarray(duty_pct, dtype=float)
    z = np.asarray(thrust, dtype=float)
    q, p = len(d), order + 1
    if d.shape != z.shape or d.ndim != 1:
        raise UserError("duty and thrust must be 1-D arrays of equal length")
    if order < 0:
        raise UserError(f"polynomial order must be non-negative, got {order}")
    if len(np.unique(d)) < p:
        raise UserError(f"an order-{order} fit needs at least {p} distinct duties, got {len(np.unique(d))}")
    if not (np.all(np.isfinite(d)) and np.all(np.isfinite(z))):
        raise UserError("duty and thrust must be finite")
    scale = float(np.max(np.abs(d))) or 1.0
    hs = design_matrix(d / scale, order)  # well conditioned on [0, 1]
    b, *_ = np.linalg.lstsq(hs, z, rcond=None)
    s = scale ** -np.arange(p, dtype=float)
    coef = b * s
    resid = z - hs @ b
    rss = float(resid @ resid)
    hth_inv = np.linalg.inv(hs.T @ hs)
    sigma2 = rss / (q - p) if q > p else math.nan
    cov = sigma2 * (s[:, None] * hth_inv * s[None, :])
    lev = np.einsum("ij,jk,ik->i", hs, hth_inv, hs)
    with np.errstate(divide="ignore", invalid="ignore"):
        loo = resid / (1.0 - lev)
    cv = float(np.sqrt(np.mean(loo ** 2))) if np.all(lev < 1 - 1e-9) else math.inf
    # Gaussian log-likelihood with the variance as a parameter: k = p + 1
    k = p + 1
    ll_term = q * math.log(max(rss, 1e-300) / q)
    aic = ll_term + 2 * k
    aicc = aic + 2 * k * (k + 1) / (q - k - 1) if q - k - 1 > 0 else math.inf
    bic = ll_term + k * math.log(q)
    return PolyFit(order, coef, cov, rss, math.sqrt(rss / q), q, aicc, bic, cv, resid)


def fit_orders(duty_pct: np.ndarray, thrust: np.ndarray,
               orders: Iterable[int] = ORDERS) -> dict[int, PolyFit]:
    """Fits of every order that the number of distinct duties allows."""
    n_distinct = len(np.unique(np.asarray(duty_pct, dtype=float)))
    return {n: fit_polynomial(duty_pct, thrust, n) for n in orders if n + 1 <= n_distinct}


def select_order(fits: Mapping[int, PolyFit], criterion: str = "aicc") -> int:
    """The order minimising ``criterion`` (``aicc``, ``bic`` or ``cv``); ties go to the lower order.

    Falls back to BIC when AICc is infinite for every order (too few steps).
    """
    if criterion not in CRITERIA:
        raise UserError(f"criterion must be one of {', '.join(CRITERIA)}, not {criterion!r}")
    if not fits:
        raise UserError("no polynomial could be fitted (too few duty steps)")
    if criterion == "aicc" and not any(math.isfinite(f.aicc) for f in fits.values()):
        criterion = "bic"
    return min(sorted(fits), key=lambda n: (fits[n].criterion(criterion), n))


@dataclass
class ThrustFit:
    """Fits for every nozzle count: ``fits[k][order]``, ``selected[k]``, and the table."""

    fits: dict[int, dict[int, PolyFit]]
    selected: dict[int, int]
    criterion: str
    order_request: str
    data: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]
    """``data[k] = (duty_pct, thrust_gf, std_gf)`` per step."""
    noise: dict[str, Any] = field(default_factory=dict)
    """How the selected fits' noise variance was set (:func:`pool_noise`)."""

    def table(self, pressure_psi: float | None = None, source: str | None = None) -> ThrustTable:
        """ThrustTable (gram-force) with the selected orders and fit statistics in ``extra``."""
        coeffs = {k: tuple(float(a) for a in self.fits[k][n].coefficients)
                  for k, n in self.selected.items()}
        duties = np.concatenate([v[0] for v in self.data.values()])
        stats: dict[str, Any] = {}
        for k, n in self.selected.items():
            f = self.fits[k][n]
            stats[str(k)] = {
                "order": n, "n_steps": f.n_points, "residual_rms_gf": f.rms,
                "cv_rms_gf": f.cv_rms, "aicc": f.aicc, "bic": f.bic,
                **({"coefficient_std": [float(math.sqrt(v)) for v in np.diag(f.covariance)],
                    "covariance": [[float(x) for x in row] for row in f.covariance]}
                   if np.all(np.isfinite(f.covariance)) and np.all(np.diag(f.covariance) >= 0)
                   else {"covariance_note": f"not determined: {f.n_points} duty steps for "
                                            f"{f.order + 1} coefficients leave no residual to "
                                            "estimate the noise from (add steps)"}),
                "orders": {str(m): {"residual_rms_gf": g.rms, "cv_rms_gf": g.cv_rms,
                                    "aicc": g.aicc, "bic": g.bic,
                                    "coefficients": [float(a) for a in g.coefficients]}
                           for m, g in self.fits[k].items()},
            }
        extra: dict[str, Any] = {}
        if source:
            extra["source"] = source
        extra["fit"] = {"criterion": self.criterion, "order": self.order_request, "nozzles": stats,
                        **({"noise": self.noise} if self.noise else {})}
        return ThrustTable(coeffs, "gf", (float(duties.min()), float(duties.max())), pressure_psi, extra)


# steps.csv columns a fit reads: must be finite numbers on every line
STEP_REQUIRED = ("n_open", "duty_pct", "thrust_gf")
# columns that may be empty/NaN (a step of one reading has no std) but not text
STEP_OPTIONAL = ("n", "std_gf", "sem_gf")


def _line_numbers(path: str | None, n_rows: int) -> list[int]:
    """File line of each data row of a CSV read by pandas (which skips blank lines)."""
    lines = list(range(2, n_rows + 2))
    if path is None:
        return lines
    try:
        with open(path, encoding="utf-8-sig", errors="replace") as f:
            numbered = [i for i, ln in enumerate(f, 1) if ln.strip()][1:]  # after the header
    except OSError:
        return lines
    return numbered[:n_rows] if len(numbered) >= n_rows else lines


def check_steps(steps: pd.DataFrame, source: str = "steps table", path: str | None = None) -> pd.DataFrame:
    """The steps table with its numeric columns as floats, or a UserError naming the
    source, the line and the column of the first cell that is not a finite number (text,
    an empty cell, NaN or infinity in ``n_open``, ``duty_pct``, ``thrust_gf``; text in
    ``n``, ``std_gf``, ``sem_gf``). A damaged step is never dropped silently: delete its
    line to leave it out of the fit. ``path``: the CSV, to count its lines exactly."""
    missing = set(STEP_REQUIRED) - set(steps.columns)
    if missing:
        raise UserError(f"{source}: lacks column(s) {', '.join(sorted(missing))}")
    out = steps.copy()
    lines = None
    for col in STEP_REQUIRED + tuple(c for c in STEP_OPTIONAL if c in steps.columns):
        raw = steps[col]
        num = pd.to_numeric(raw, errors="coerce").astype(float)
        vals = num.to_numpy()
        text = raw.notna().to_numpy() & np.isnan(vals)
        bad = text | (~np.isfinite(vals) if col in STEP_REQUIRED else np.zeros(len(vals), bool))
        if bad.any():
            i = int(np.argmax(bad))
            lines = lines or _line_numbers(path, len(steps))
            cell = raw.iloc[i]
            what = (f"{str(cell).strip()!r} is not a number" if text[i] else
                    "empty or NaN" if pd.isna(cell) else f"{vals[i]:g} is not a finite number")
            more = int(bad.sum()) - 1
            raise UserError(f"{source}: line {lines[i]}: column {col}: {what}"
                            + (f" ({more} more line(s) like it)" if more else "")
                            + ("; delete the line to leave that step out of the fit"
                               if col == "thrust_gf" else ""))
        out[col] = num
    return out


def fit_steps(steps: pd.DataFrame, order: str | int = "auto", criterion: str = "aicc",
              orders: Iterable[int] = ORDERS, source: str = "steps table",
              path: str | None = None) -> ThrustFit:
    """Fit per-step mean thrust (steps.csv columns ``n_open, duty_pct, thrust_gf``) per nozzle count.

    ``order`` is ``"auto"`` (pick by ``criterion``) or a fixed order 1-4. A cell that is
    not a finite number is a UserError naming ``source`` (``path``), line and column
    (:func:`check_steps`).
    """
    steps = check_steps(steps, source, path)
    if order != "auto":
        try:
            order = int(order)
        except ValueError:
            raise UserError(f"order must be auto or 1-4, not {order!r}") from None
        if order not in ORDERS:
            raise UserError(f"order must be auto or 1-4, not {order}")
    good = steps
    if good.empty:
        raise UserError("no completed duty steps to fit")
    fits, selected, data = {}, {}, {}
    for k, g in good.groupby("n_open", sort=True):
        d = g["duty_pct"].to_numpy(dtype=float)
        z = g["thrust_gf"].to_numpy(dtype=float)
        sd = g["std_gf"].to_numpy(dtype=float) if "std_gf" in g else np.full_like(z, np.nan)
        fk = fit_orders(d, z, orders)
        if not fk:
            raise UserError(f"{int(k)} nozzle(s): {len(np.unique(d))} distinct duty step(s) is too few to fit")
        if order == "auto":
            selected[int(k)] = select_order(fk, criterion)
        else:
            if order not in fk:
                raise UserError(f"{int(k)} nozzle(s): an order-{order} fit needs at least "
                                f"{order + 1} distinct duty steps, got {len(np.unique(d))}")
            selected[int(k)] = order
        fits[int(k)] = fk
        data[int(k)] = (d, z, sd)
    noise = pool_noise(fits, selected)
    return ThrustFit(fits, selected, criterion, str(order), data, noise)


POOL_ALPHA = 0.01
"""Bartlett's test level below which the note warns of unequal variances."""


def pool_noise(fits: dict[int, dict[int, PolyFit]], selected: Mapping[int, int]) -> dict[str, Any]:
    """Rescale the covariance of every selected fit (in place in ``fits``) by ``nu / (nu -
    2)`` (module doc); returns what was done (JSON-ready). A count with ``nu <= 2`` residual
    dof: every count then takes the variance pooled over the counts (and their summed
    ``nu``); a variance that still rests on ``nu <= 2`` has no finite t variance: its
    covariance stays ``s^2`` and the note says so."""
    sel = {k: fits[k][n] for k, n in selected.items()}
    dof = {k: f.n_points - f.order - 1 for k, f in sel.items()}
    used = [k for k in sel if dof[k] > 0 and sel[k].rss > 0]
    if not used:
        return {}
    nu_all = sum(dof[k] for k in used)
    pooled = sum(sel[k].rss for k in used) / nu_all
    p_value = math.nan
    if len(used) > 1:
        s2 = np.array([sel[k].rss / dof[k] for k in used])
        nu = np.array([dof[k] for k in used], dtype=float)
        c = 1.0 + (np.sum(1.0 / nu) - 1.0 / nu_all) / (3.0 * (len(used) - 1))
        stat = float((nu_all * math.log(pooled) - np.sum(nu * np.log(s2))) / c)
        p_value = chi2_sf(stat, len(used) - 1)
    pool = min(dof[k] for k in used) <= 2 and len(used) > 1
    out: dict[str, Any] = {"pooled": bool(pool), "bartlett_p": p_value, "nozzles": {}}
    for k in used:
        f = sel[k]
        s2_k, nu_k = (pooled, nu_all) if pool else (f.rss / dof[k], dof[k])
        inflate = nu_k / (nu_k - 2.0) if nu_k > 2 else 1.0
        factor = s2_k * inflate / (f.rss / dof[k])
        fits[k][f.order] = replace(f, covariance=f.covariance * factor)
        out["nozzles"][str(k)] = {"variance_gf2": s2_k * inflate, "dof": nu_k,
                                  "t_inflation": inflate}
    worst = nu_all if pool else min(dof[k] for k in used)
    bartlett = f"Bartlett p = {p_value:.3g}" if math.isfinite(p_value) else ""
    if pool:
        note = (f"residual variances of the nozzle counts pooled ({bartlett}), {nu_all} dof, "
                "scaled by nu/(nu-2)")
        if p_value < POOL_ALPHA:
            note += ("; the counts' variances look unequal: the pooled one may understate "
                     "the noisiest count (add duty steps to fit each on its own)")
    else:
        note = ("each nozzle count's own residual variance, scaled by nu/(nu-2)"
                + (f" ({bartlett})" if bartlett else ""))
    if worst <= 2:
        note += (f"; {worst} residual dof leave the variance itself unknown (Student-t "
                 "without a finite variance): the covariance is s^2 alone and understates "
                 "the error; add duty steps")
    out["note"] = note
    return out


def max_error_pct_full_scale(table: ThrustTable, reference: ThrustTable,
                             duty_pct: np.ndarray | None = None) -> dict[int, float]:
    """Per nozzle count, max |table - reference| over ``duty_pct`` (default 10-90 % in 1 % steps)
    as a percentage of the reference's full scale (its largest value over those duties)."""
    d = np.arange(10.0, 90.0 + 1e-9, 1.0) if duty_pct is None else np.asarray(duty_pct, dtype=float)
    out = {}
    for k in sorted(set(table.coefficients) & set(reference.coefficients)):
        ref = reference.per_nozzle(d, k)
        fs = float(np.max(np.abs(ref)))
        out[k] = 100.0 * float(np.max(np.abs(table.per_nozzle(d, k) - ref))) / fs
    return out


LINEARITY_READABILITY = 2.0
"""A balance's linearity in readability steps d: OHAUS states +/-2 d for the 0.01 g Scout
models (for example +/-0.02 g at d = 0.01 g). Override with ``linearity_g``."""


def readability_g(readings_gf: np.ndarray) -> float:
    """The balance's display step d, g: the smallest non-zero difference between readings
    (rounded to 1, 2 or 5 x 10^n); NaN when the readings do not show one."""
    r = np.asarray(readings_gf, dtype=float)
    r = np.unique(np.round(r[np.isfinite(r)], 6))
    steps = np.diff(r)
    steps = steps[steps > 1e-9]
    if steps.size == 0:
        return math.nan
    d = float(np.min(steps))
    e = 10.0 ** math.floor(math.log10(d))
    d = min((m * e for m in (1.0, 2.0, 5.0, 10.0)), key=lambda c: abs(c - d))
    q = r / d
    if np.mean(np.abs(q - np.round(q)) < 0.01) < 0.95:
        return math.nan  # not a display step: the readings are not multiples of it
    return d


def table_uncertainty(steps: pd.DataFrame, readings_gf: np.ndarray | None = None, *,
                      linearity_g: float | None = None, extra_rel: float = 0.0,
                      extra_source: str = ""):
    """The systematic part of a fitted table's uncertainty, ``[uncertainty]`` (the
    statistical part is the fit's coefficient covariance).

    ``scale_rel = sqrt((L / sqrt(3) / T_med)^2 + extra_rel^2)``: the balance's linearity
    ``L`` (a +/- bound, read as uniform), relative to the median step thrust ``T_med``; and
    ``extra_rel``, what the session cannot measure (accumulator pressure set-point, PWM
    frequency differences between bench and run), as the user states it. ``L`` is
    ``linearity_g`` or 2 d with d measured from the readings. Zero drift and repeatability
    are random per step: they are in the fit's residuals and so in its covariance.
    Returns a :class:`common.thrust_uncertainty.ThrustUncertainty`.
    """
    from common.thrust_uncertainty import ThrustUncertainty

    thrust = steps["thrust_gf"].to_numpy(dtype=float)
    thrust = thrust[np.isfinite(thrust) & (thrust > 0)]
    if thrust.size == 0:
        raise UserError("no completed duty steps: cannot state the table's uncertainty")
    t_med = float(np.median(thrust))
    how = []
    if linearity_g is None:
        d = readability_g(readings_gf) if readings_gf is not None else math.nan
        if math.isfinite(d):
            linearity_g = LINEARITY_READABILITY * d
            how.append(f"balance linearity +/-{linearity_g:g} g (2 x readability {d:g} g "
                       "measured from the readings, OHAUS Scout spec)")
        else:
            how.append("balance linearity NOT included: the readings show no display step "
                       "(give --balance-linearity-g)")
    else:
        how.append(f"balance linearity +/-{linearity_g:g} g (--balance-linearity-g)")
    bal = 0.0 if linearity_g is None else linearity_g / math.sqrt(3.0) / t_med
    if linearity_g is not None:
        how[-1] += f" over the median step thrust {t_med:.3g} gf: {bal:.2%}"
    if extra_rel > 0:
        how.append(f"{extra_rel:.2%} stated by the user ({extra_source or '--scale-rel'})")
    else:
        how.append("NOT included: accumulator pressure set-point and PWM frequency differences "
                   "between bench and run (add them with --scale-rel or edit scale_rel)")
    scale = math.hypot(bal, extra_rel)
    return ThrustUncertainty(scale, {}, {"scale_rel": "; ".join(how)})
