"""The chi-square distribution's tail and quantile, computed as ``scipy.stats.chi2`` computes
them (``sf = chdtrc``, ``isf = chdtri``, ``ppf = 2 gammaincinv(df/2, p)``) from ``scipy.special`` alone.

``import scipy.stats`` costs about 0.6 s of CPU per process here (it loads scipy.spatial,
scipy.optimize and the docstring machinery of every distribution); every ``tpods estimate``
command paid it for two functions. Equality with scipy.stats is tested.
"""

from __future__ import annotations

import numpy as np
from scipy import special


def sf(x, df):
    """P(X > x) for X ~ chi-square with ``df`` degrees of freedom (arrays broadcast);
    1 for x <= 0."""
    x = np.asarray(x, dtype=float)
    out = special.chdtrc(df, np.maximum(x, 0.0))
    return np.where(x <= 0, 1.0, out) if out.ndim else (1.0 if x <= 0 else float(out))


def ppf(p, df):
    """The quantile: x with P(X <= x) = p, for p in [0, 1] (arrays broadcast)."""
    p = np.asarray(p, dtype=float)
    if np.any((p < 0) | (p > 1)):
        raise ValueError("a probability lies in [0, 1]")
    out = 2.0 * special.gammaincinv(np.asarray(df, dtype=float) / 2.0, p)
    return out if np.ndim(out) else float(out)


def isf(q, df):
    """The upper quantile: x with P(X > x) = q, for q in [0, 1] (arrays broadcast)."""
    q = np.asarray(q, dtype=float)
    if np.any((q < 0) | (q > 1)):
        raise ValueError("a probability lies in [0, 1]")
    out = special.chdtri(df, q)
    return out if np.ndim(out) else float(out)
