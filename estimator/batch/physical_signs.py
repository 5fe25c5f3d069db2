"""Signs a physical parameter cannot have, said out loud: a linear or
rotational damping ``ct``, ``cr`` below zero (drag that pushes) or a shared-supply drop
below zero (thrust that grows with more valves open). On a real run the fit can reach such
a value when the model absorbs an unmodelled effect into the parameter; it is a warning
naming the parameter, its value and sigma, not a clamp: on frictionless simulated data the
estimates straddle 0 within their sigma and are left alone (only beyond
:data:`SIGN_SIGMAS` sigma is a sign reported)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

SIGN_SIGMAS = 3.0
"""A parameter below zero by more than this many of its sigmas is reported."""

NONNEGATIVE = {"ct": "negative linear damping", "cr": "negative rotational damping",
               "drop": "a negative supply drop"}
"""Parameters that cannot be negative, with what a negative value would mean."""


def _what(name: str) -> str | None:
    """What a negative value of ``name`` means, or None for a parameter of either sign."""
    if name.startswith("drop."):
        return NONNEGATIVE["drop"]
    return NONNEGATIVE.get(name)


def unphysical(names: Sequence[str], values: Mapping[str, float],
               sigmas: Mapping[str, float], k_sigma: float = SIGN_SIGMAS
               ) -> dict[str, tuple[float, float]]:
    """``name -> (value, sigma)`` of each sign-bound parameter below zero by more than
    ``k_sigma`` sigma (a parameter with no finite sigma is judged by its value alone)."""
    out: dict[str, tuple[float, float]] = {}
    for n in names:
        if _what(n) is None or n not in values:
            continue
        v = float(values[n])
        s = float(sigmas.get(n, math.nan))
        bound = k_sigma * s if math.isfinite(s) else 0.0
        if v < 0 and -v > bound:
            out[n] = (v, s)
    return out


def sign_warnings(names: Sequence[str], values: Mapping[str, float],
                  sigmas: Mapping[str, float], k_sigma: float = SIGN_SIGMAS) -> list[str]:
    """One line per parameter of :func:`unphysical`, naming it, its value and sigma."""
    lines = []
    for n, (v, s) in unphysical(names, values, sigmas, k_sigma).items():
        sig = f" +- {s:.3g} ({-v / s:.1f} sigma below 0)" if math.isfinite(s) and s > 0 else ""
        kind = "damping" if n in ("ct", "cr") else "supply drop"
        lines.append(f"{n} = {v:.4g}{sig}: {_what(n)} is not physical: the model absorbs an "
                     f"unmodelled effect into it (a negative {kind} is no estimate of one; "
                     "look at the misfit warnings and compare the models with --model auto)")
    return lines


def result_sign_warnings(res, k_sigma: float = SIGN_SIGMAS) -> list[str]:
    """:func:`sign_warnings` of a batch result (``names``, ``params``, ``sigma`` after the
    six initial-state entries)."""
    names = tuple(res.names)
    sig = {n: float(res.sigma[6 + i]) for i, n in enumerate(names)}
    vals = {n: float(res.params.get(n, res.z0[6 + i])) for i, n in enumerate(names)}
    return sign_warnings(names, vals, sig, k_sigma)
