"""Model selection between the nested plant models and residual diagnostics.

The models of :mod:`estimator.plant.parameter_sets` are nested (ideal < friction < friction+tilt).
Each is fitted by batch least squares (:func:`estimator.batch.least_squares.batch_ls`); with Gaussian
pose noise of the assumed standard deviations the weighted residual sum of squares
``chi2 = sum r^T R^-1 r`` is ``-2 log L`` up to a constant, so:

- likelihood-ratio test between nested models: ``LR = chi2_small - chi2_big`` is
  chi-square with ``df = p_big - p_small`` degrees of freedom when the small model is
  true. The assumed noise may be wrong on real data; the statistic is divided by
  ``max(1, s2)`` with ``s2 = chi2_big / (n_obs - k_big)`` the reduced chi-square of the
  largest model (an F-test-like guard that never makes the test *less* conservative);
- AIC = chi2 + 2k and BIC = chi2 + k ln(n_obs), k = 6 + p (initial state + parameters);
- whiteness: the Ljung-Box portmanteau test on each normalised residual channel
  (x, y, yaw) in pose order; an under-modelled run leaves slow, strongly autocorrelated
  residuals.

:func:`select_model` implements ``--model auto``: starting from ``ideal`` it moves to a
larger model while the likelihood-ratio test rejects the smaller one at level
``alpha`` (default 1e-3, so on frictionless data ``ideal`` is kept in 99.9 % of runs
per test), and returns the choice with its reason.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from common import chi2 as chi2_dist  # scipy.stats.chi2 without its import cost
from common.errors import UserError
from estimator.plant.parameter_sets import MODELS, fixed_for

DEFAULT_ALPHA = 1e-3
DEFAULT_LAGS = 20


def ljung_box(x: np.ndarray, lags: int = DEFAULT_LAGS) -> tuple[float, float, np.ndarray]:
    """Ljung-Box test of whiteness of one residual series.

    Args:
        x: (N,) residuals in time order (any scale; the mean is removed).
        lags: number of autocorrelation lags h.

    Returns:
        ``(Q, p_value, acf)`` with ``Q = N (N+2) sum_k rho_k^2 / (N-k)`` (k = 1..h),
        ``p = P(chi2_h > Q)`` and ``acf`` (h+1,) the sample autocorrelation (acf[0] = 1).
    """
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    n = len(x)
    lags = int(min(lags, n - 2))
    if lags < 1:
        return float("nan"), float("nan"), np.ones(1)
    d = x - x.mean()
    denom = float(d @ d)
    if denom <= 0:
        return 0.0, 1.0, np.concatenate([[1.0], np.zeros(lags)])
    acf = np.array([1.0] + [float(d[:-k] @ d[k:]) / denom for k in range(1, lags + 1)])
    k = np.arange(1, lags + 1)
    q = float(n * (n + 2) * np.sum(acf[1:] ** 2 / (n - k)))
    return q, float(chi2_dist.sf(q, lags)), acf


@dataclass
class ModelFit:
    """One model's batch fit and its diagnostics.

    Attributes:
        model: option name; names: estimated parameters; result: the BatchResult.
        chi2: weighted residual sum of squares (``-2 log L`` + const); n_obs: 3 N; k: 6 + p.
        aic, bic: information criteria (smaller is better).
        reduced_chi2: chi2 / (n_obs - k) (about 1 for a correct model and noise).
        lb_q, lb_p: Ljung-Box statistic and p-value per channel (x, y, yaw).
        acf: (3, lags+1) residual autocorrelation per channel.
    """

    model: str
    names: tuple[str, ...]
    result: Any
    chi2: float
    n_obs: int
    k: int
    aic: float
    bic: float
    reduced_chi2: float
    lb_q: np.ndarray
    lb_p: np.ndarray
    acf: np.ndarray
    start: str = "default start"

    @property
    def white(self) -> bool:
        """No channel rejects whiteness at the 1 % level."""
        return bool(np.all(self.lb_p > 0.01))

    def to_dict(self) -> dict[str, Any]:
        r = self.result
        return {"model": self.model, "estimated": list(self.names), "converged": r.converged,
                "mass_kg": r.mass_kg, "mass_sigma_kg": r.mass_sigma_kg,
                "izz_kgm2": r.izz_kgm2, "izz_sigma_kgm2": r.izz_sigma_kgm2,
                "params": {n: float(r.z0[6 + i]) for i, n in enumerate(self.names)},
                "sigmas": {n: float(r.sigma[6 + i]) for i, n in enumerate(self.names)},
                "chi2": self.chi2, "n_obs": self.n_obs, "k": self.k, "aic": self.aic,
                "bic": self.bic, "reduced_chi2": self.reduced_chi2,
                "ljung_box_q": self.lb_q.tolist(), "ljung_box_p": self.lb_p.tolist(),
                "white": self.white, "start": self.start}


def diagnose(model: str, result, sigma_pos_m: float, sigma_yaw_rad: float,
             lags: int = DEFAULT_LAGS) -> ModelFit:
    """Likelihood, information criteria and residual whiteness of one batch fit."""
    res = np.asarray(result.residuals, float)
    sig = np.array([sigma_pos_m, sigma_pos_m, sigma_yaw_rad])
    norm = res / sig
    chi2 = float(np.sum(norm**2))
    n_obs = int(norm.size)
    k = 6 + len(result.names)
    qs, ps, acfs = [], [], []
    for j in range(3):
        q, p, acf = ljung_box(norm[:, j], lags)
        qs.append(q)
        ps.append(p)
        acfs.append(np.pad(acf, (0, max(0, lags + 1 - len(acf))), constant_values=np.nan))
    return ModelFit(model, tuple(result.names), result, chi2, n_obs, k, chi2 + 2 * k,
                    chi2 + k * math.log(max(n_obs, 1)), chi2 / max(n_obs - k, 1),
                    np.array(qs), np.array(ps), np.array(acfs))


@dataclass
class LRTest:
    """Likelihood-ratio test of ``small`` against the larger nested ``big``."""

    small: str
    big: str
    stat: float        # chi2_small - chi2_big (may be < 0 if the big fit did not converge)
    df: int
    scale: float       # max(1, reduced chi2 of the largest model)
    p_value: float     # P(chi2_df > stat / scale)

    def to_dict(self) -> dict[str, Any]:
        return {"small": self.small, "big": self.big, "lr": self.stat, "df": self.df,
                "noise_scale": self.scale, "p_value": self.p_value}


def lr_test(small: ModelFit, big: ModelFit, scale: float = 1.0) -> LRTest:
    stat = small.chi2 - big.chi2
    df = big.k - small.k
    p = float(chi2_dist.sf(max(stat, 0.0) / scale, df)) if df > 0 else float("nan")
    return LRTest(small.model, big.model, stat, df, scale, p)


@dataclass
class ModelSelection:
    """Result of :func:`select_model`.

    Attributes:
        chosen: the selected model option; reason: one sentence saying why.
        fits: model -> ModelFit (every candidate); tests: the likelihood-ratio tests made.
        alpha: the test level; by_aic, by_bic: the models minimising AIC and BIC.
    """

    chosen: str
    reason: str
    fits: dict[str, ModelFit]
    tests: list[LRTest]
    alpha: float
    by_aic: str
    by_bic: str
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {"chosen": self.chosen, "reason": self.reason, "alpha": self.alpha,
                "by_aic": self.by_aic, "by_bic": self.by_bic,
                "tests": [t.to_dict() for t in self.tests],
                "fits": {k: f.to_dict() for k, f in self.fits.items()}, "notes": self.notes}

    def table_lines(self) -> list[str]:
        """A readable comparison table (one line per model) plus the tests and the decision."""
        lines = [f"  {'model':<14} {'mass kg':>9} {'Izz kg m^2':>11} {'chi2':>10} {'AIC':>10} "
                 f"{'BIC':>10} {'red.chi2':>8}  Ljung-Box p (x, y, yaw)"]
        for m, f in self.fits.items():
            r = f.result
            lines.append(f"  {m:<14} {r.mass_kg:9.4f} {r.izz_kgm2:11.4e} {f.chi2:10.1f} "
                         f"{f.aic:10.1f} {f.bic:10.1f} {f.reduced_chi2:8.3f}  "
                         + ", ".join(f"{p:.2g}" for p in f.lb_p)
                         + ("" if r.converged else "  (not converged)"))
        lines.extend(f"  start of {m}: {f.start}" for m, f in self.fits.items()
                     if f.start != "default start")
        for t in self.tests:
            lines.append(f"  LR {t.small} -> {t.big}: {t.stat:.1f} on {t.df} df"
                         + (f" (/ {t.scale:.2f} noise scale)" if t.scale > 1.05 else "")
                         + f", p = {t.p_value:.3g}")
        lines.append(f"  chosen: {self.chosen}: {self.reason}")
        lines.extend(f"  note: {n}" for n in self.notes)
        return lines


def decide(fits: Mapping[str, ModelFit], alpha: float = DEFAULT_ALPHA) -> ModelSelection:
    """Choose among fitted nested models by sequential likelihood-ratio tests.

    From the smallest model, move to the next larger one whenever the test of the
    current model against it rejects at ``alpha``; if a step is not significant, the
    current model is still tested against every larger model (so tilt alone, with no
    friction, is detected by ideal -> friction+tilt).
    """
    order = [m for m in MODELS if m in fits]
    if not order:
        raise ValueError("no model fits to choose from")
    largest = fits[order[-1]]
    scale = max(1.0, largest.reduced_chi2)
    tests: list[LRTest] = []
    current = order[0]
    i = 0
    why = []
    while i < len(order) - 1:
        moved = False
        for j in range(i + 1, len(order)):
            t = lr_test(fits[current], fits[order[j]], scale)
            tests.append(t)
            if t.p_value < alpha:
                why.append(f"{order[j]} fits significantly better than {current} "
                           f"(LR {t.stat:.1f} on {t.df} df, p = {t.p_value:.2g} < {alpha:g})")
                current, i, moved = order[j], j, True
                break
        if not moved:
            break
    if current == order[0]:
        worst = min((t.p_value for t in tests), default=float("nan"))
        reason = (f"no larger model fits significantly better (smallest p = {worst:.2g} >= "
                  f"{alpha:g}): the extra terms are not supported by the data")
    else:
        reason = "; ".join(why)
        rest = [t for t in tests if t.small == current]
        if rest:
            reason += "; " + "; ".join(f"{t.big} does not improve on it (p = {t.p_value:.2g})"
                                       for t in rest)
    notes = []
    if scale > 1.5:
        notes.append(f"the largest model's reduced chi-square is {scale:.2f}: the assumed pose "
                     "noise is too small or the plant is still mis-modelled; the tests were "
                     "scaled by it")
    if not fits[current].white:
        notes.append(f"the residuals of {current} are not white (Ljung-Box p = "
                     + ", ".join(f"{p:.2g}" for p in fits[current].lb_p)
                     + "): unmodelled dynamics remain")
    for m in order:
        if not fits[m].result.converged:
            notes.append(f"the {m} fit did not converge; its test is unreliable")
    by_aic = min(order, key=lambda m: fits[m].aic)
    by_bic = min(order, key=lambda m: fits[m].bic)
    return ModelSelection(current, reason, dict(fits), tests, alpha, by_aic, by_bic, notes)


def fit_models(pose_t, pose, cmd_t, thrust_n, models: Sequence[str] = tuple(MODELS), *,
               fixed: Mapping[str, float] | None = None,
               initial: Mapping[str, float] | None = None,
               sigma_pos_m: float = 0.01, sigma_yaw_rad: float = math.radians(1.0),
               lags: int = DEFAULT_LAGS, extra_names: Sequence[str] = (),
               warm: bool = False, start_label: str = "default start",
               **kwargs) -> dict[str, ModelFit]:
    """Fit each model by batch least squares and diagnose it.

    ``fixed`` holds known values of parameters a model does not estimate (e.g. ``arm``);
    entries a model estimates are dropped for that model. ``extra_names`` are estimated in
    every model besides its own (a structure's cx, cy). Other keywords go to batch_ls.
    ``warm``: each larger model starts at the last converged smaller model's optimum (its
    extra parameters at their fixed values), and from ``initial`` only if that fails;
    otherwise from ``initial`` and from the nested start when that does better.
    ``start_label`` names ``initial`` in each fit's ``start``.
    """
    if warm:
        return _fit_warm(pose_t, pose, cmd_t, thrust_n, models, fixed=fixed, initial=initial,
                         sigma_pos_m=sigma_pos_m, sigma_yaw_rad=sigma_yaw_rad, lags=lags,
                         extra_names=extra_names, start_label=start_label, **kwargs)
    from estimator.batch.least_squares import batch_ls

    out: dict[str, ModelFit] = {}
    prev: ModelFit | None = None
    for m in models:
        names = MODELS[m] + tuple(n for n in extra_names if n not in MODELS[m])
        fx = fixed_for(m, {k: v for k, v in (fixed or {}).items() if k not in names})
        init = {k: v for k, v in (initial or {}).items() if k not in fx}
        kw = dict(names=names, fixed=fx, sigma_pos_m=sigma_pos_m, sigma_yaw_rad=sigma_yaw_rad,
                  **kwargs)
        fit: ModelFit | None = None
        error: UserError | None = None
        try:
            fit = diagnose(m, batch_ls(pose_t, pose, cmd_t, thrust_n, initial=init, **kw),
                           sigma_pos_m, sigma_yaw_rad, lags)
        except UserError as exc:  # e.g. a start-up stage ending where the trajectory blows up
            error = exc
        if prev is not None and set(prev.names) < set(names) and (
                fit is None or not fit.result.converged or fit.chi2 > prev.chi2 * (1 + 1e-9)):
            # The smaller model's optimum is a point of this one (extras at their fixed
            # values): restart there, so the nested fit can only improve on it.
            warm = _nested_start(prev, names, fx)
            kw2 = {**kw, "horizon0_s": None}
            try:
                alt = diagnose(m, batch_ls(pose_t, pose, cmd_t, thrust_n, initial=warm, **kw2),
                               sigma_pos_m, sigma_yaw_rad, lags)
                alt.start = f"nested start at the {prev.model} optimum"
            except UserError as exc:
                alt, error = None, error or exc
            if alt is not None and (fit is None or (alt.result.converged and (
                    not fit.result.converged or alt.chi2 < fit.chi2))):
                fit = alt
        if fit is None:
            raise UserError(f"the {m} fit failed: {error}")
        if fit.start == "default start":
            fit.start = start_label
        out[m] = fit
        if fit.result.converged:
            prev = fit
    return out


def _fit_warm(pose_t, pose, cmd_t, thrust_n, models: Sequence[str], *, fixed, initial,
              sigma_pos_m: float, sigma_yaw_rad: float, lags: int, extra_names: Sequence[str],
              start_label: str, **kwargs) -> dict[str, ModelFit]:
    """:func:`fit_models` with ``warm``: the smallest model from ``initial``, each larger
    one first from the last converged smaller model's optimum."""
    from estimator.batch.least_squares import batch_ls

    out: dict[str, ModelFit] = {}
    prev: ModelFit | None = None
    for m in models:
        names = MODELS[m] + tuple(n for n in extra_names if n not in MODELS[m])
        fx = fixed_for(m, {k: v for k, v in (fixed or {}).items() if k not in names})
        kw = dict(names=names, fixed=fx, sigma_pos_m=sigma_pos_m, sigma_yaw_rad=sigma_yaw_rad,
                  **kwargs)
        tries: list[tuple[Any, str, dict]] = []
        if prev is not None and set(prev.names) < set(names):
            tries.append((_nested_start(prev, names, fx),
                          f"warm start at the {prev.model} optimum", {**kw, "horizon0_s": None}))
        tries.append(({k: v for k, v in (initial or {}).items() if k not in fx}, start_label, kw))
        fit, error = None, None
        for init, label, kwi in tries:
            try:
                alt = diagnose(m, batch_ls(pose_t, pose, cmd_t, thrust_n, initial=init, **kwi),
                               sigma_pos_m, sigma_yaw_rad, lags)
            except UserError as exc:
                error = error or exc
                continue
            alt.start = label
            if fit is None or (alt.result.converged and (
                    not fit.result.converged or alt.chi2 < fit.chi2)):
                fit = alt
            if fit.result.converged:
                break
        if fit is None:
            raise UserError(f"the {m} fit failed: {error}")
        out[m] = fit
        if fit.result.converged:
            prev = fit
    return out


def _nested_start(small: ModelFit, names: Sequence[str], fixed: Mapping[str, float]) -> np.ndarray:
    """(6+p,) start vector of a larger model at a smaller model's optimum."""
    r = small.result
    z = np.zeros(6 + len(names))
    z[:6] = r.z0[:6]
    for j, n in enumerate(names):
        z[6 + j] = r.params.get(n, fixed.get(n, 0.0))
    return z


def select_model(pose_t, pose, cmd_t, thrust_n, *, alpha: float = DEFAULT_ALPHA,
                 models: Sequence[str] = tuple(MODELS), **kwargs) -> ModelSelection:
    """``--model auto``: fit every candidate model and choose by likelihood-ratio tests."""
    return decide(fit_models(pose_t, pose, cmd_t, thrust_n, models, **kwargs), alpha)
