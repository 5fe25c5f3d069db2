"""The chi-square distribution's tail and quantiles in numpy and ``math`` alone.

Hand-written because the library costs a process start: ``import scipy.special`` adds
0.27-0.30 s of CPU to a fresh process that imports numpy (``make bench``, row "common.chi2
against scipy.special"; ``import scipy.stats`` about 0.7 s), and the live estimator and
the fits that use these functions import no other part of scipy. They are the regularized incomplete gamma function (series below
``a + 1``, Lentz's continued fraction above; Numerical Recipes 6.2) and its inverse by
Halley steps from the Wilson-Hilferty start, bracketed. Agreement with scipy.stats to
1e-12 relative is tested (tests/common/test_chi2.py).
"""

from __future__ import annotations

import math

import numpy as np

_EPS = 1e-16
_TINY = 1e-300


def _lower_series(a: float, x: float, lg: float) -> float:
    """P(a, x) by its series (x < a + 1)."""
    ap, term = a, 1.0 / a
    total = term
    for _ in range(100000):
        ap += 1.0
        term *= x / ap
        total += term
        if abs(term) < abs(total) * _EPS:
            break
    return total * math.exp(-x + a * math.log(x) - lg)


def _upper_fraction(a: float, x: float, lg: float) -> float:
    """Q(a, x) by its continued fraction (x >= a + 1), modified Lentz."""
    b = x + 1.0 - a
    c = 1.0 / _TINY
    d = 1.0 / b
    h = d
    for i in range(1, 100000):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        d = _TINY if abs(d) < _TINY else d
        c = b + an / c
        c = _TINY if abs(c) < _TINY else c
        d = 1.0 / d
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < _EPS:
            break
    return math.exp(-x + a * math.log(x) - lg) * h


def _pq(a: float, x: float) -> tuple[float, float]:
    """(P, Q) regularized incomplete gamma of shape ``a`` at ``x`` >= 0."""
    if x <= 0.0:
        return 0.0, 1.0
    if math.isinf(x):
        return 1.0, 0.0
    lg = math.lgamma(a)
    if x < a + 1.0:
        p = _lower_series(a, x, lg)
        return p, 1.0 - p
    q = _upper_fraction(a, x, lg)
    return 1.0 - q, q


def _sf1(x: float, df: float) -> float:
    if not x > 0.0:
        return 1.0 if not math.isnan(x) else math.nan
    return _pq(0.5 * df, 0.5 * x)[1]


def _quantile(target: float, df: float, upper: bool) -> float:
    """x with Q(x) = target (``upper``) or P(x) = target: Halley steps on
    ``err = P - p`` (or ``q - Q``: the same function, without 1 - q's rounding), both rising
    with x at the density's rate, kept inside a bracket that every step narrows."""
    if math.isnan(target):
        return math.nan
    if (target <= 0.0 and not upper) or (target >= 1.0 and upper):
        return 0.0
    if (target >= 1.0 and not upper) or (target <= 0.0 and upper):
        return math.inf
    a = 0.5 * df
    lg = math.lgamma(a)
    z = -_normal_quantile(target) if upper else _normal_quantile(target)
    h = 2.0 / (9.0 * df)
    g = 0.5 * df * max(1.0 - h + z * math.sqrt(h), 1e-2) ** 3  # Wilson-Hilferty, x / 2
    lo, hi = 0.0, math.inf
    for _ in range(300):
        p, q = _pq(a, g)
        err = (target - q) if upper else p - target
        if err == 0.0:
            break
        if err > 0:
            hi = g
        else:
            lo = g
        dens = math.exp((a - 1.0) * math.log(g) - g - lg)
        new = math.nan
        if dens > 0.0 and math.isfinite(dens):
            u = err / dens
            new = g - u / max(1.0 - 0.5 * u * ((a - 1.0) / g - 1.0), 0.1)
        if not lo < new < hi:
            new = 0.5 * (lo + hi) if math.isfinite(hi) else 4.0 * g
        if abs(new - g) <= 4e-16 * g:
            g = new
            break
        g = new
    return 2.0 * g


def _normal_quantile(p: float) -> float:
    """Standard normal quantile (Acklam's rational approximation, ~1e-9; a start only)."""
    a = (-3.969683028665376e+01, 2.209460984245205e+02, -2.759285104469687e+02,
         1.383577518672690e+02, -3.066479806614716e+01, 2.506628277459239e+00)
    b = (-5.447609879822406e+01, 1.615858368580409e+02, -1.556989798598866e+02,
         6.680131188771972e+01, -1.328068155288572e+01)
    c = (-7.784894002430293e-03, -3.223964580411365e-01, -2.400758277161838e+00,
         -2.549732539343734e+00, 4.374664141464968e+00, 2.938163982698783e+00)
    d = (7.784695709041462e-03, 3.224671290700398e-01, 2.445134137142996e+00,
         3.754408661907416e+00)
    if p < 0.02425:
        q = math.sqrt(-2.0 * math.log(p))
        return (((((c[0] * q + c[1]) * q + c[2]) * q + c[3]) * q + c[4]) * q + c[5]) / \
            ((((d[0] * q + d[1]) * q + d[2]) * q + d[3]) * q + 1.0)
    if p > 1.0 - 0.02425:
        return -_normal_quantile(1.0 - p)
    q = p - 0.5
    r = q * q
    return (((((a[0] * r + a[1]) * r + a[2]) * r + a[3]) * r + a[4]) * r + a[5]) * q / \
        (((((b[0] * r + b[1]) * r + b[2]) * r + b[3]) * r + b[4]) * r + 1.0)


def _apply(fn, x, df):
    xb, dfb = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(df, dtype=float))
    out = np.array([fn(float(u), float(k)) for u, k in zip(xb.ravel(), dfb.ravel(), strict=True)])
    return out.reshape(xb.shape) if xb.ndim else float(out[0])


def _check_prob(p) -> None:
    if np.any((np.asarray(p, dtype=float) < 0) | (np.asarray(p, dtype=float) > 1)):
        raise ValueError("a probability lies in [0, 1]")


def sf(x, df):
    """P(X > x) for X ~ chi-square with ``df`` degrees of freedom (arrays broadcast);
    1 for x <= 0."""
    return _apply(_sf1, x, df)


def ppf(p, df):
    """The quantile: x with P(X <= x) = p, for p in [0, 1] (arrays broadcast)."""
    _check_prob(p)
    return _apply(lambda u, k: _quantile(u, k, upper=False), p, df)


def isf(q, df):
    """The upper quantile: x with P(X > x) = q, for q in [0, 1] (arrays broadcast)."""
    _check_prob(q)
    return _apply(lambda u, k: _quantile(u, k, upper=True), q, df)
