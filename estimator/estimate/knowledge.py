"""What a structure's ``[body]`` table makes of the unknowns (partly known
properties): :class:`BodyKnowledge` and :func:`body_knowledge`, shared by the estimates
(:func:`estimator.estimate.estimate_run`) and the bound
(:func:`estimator.estimate.bound_sequence`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from common.errors import UserError
from estimator.estimate.options import STRUCTURE_ESTIMATE


@dataclass(frozen=True)
class BodyKnowledge:
    """What a structure's ``[body]`` table makes of the unknowns (:func:`body_knowledge`).

    ``names`` the parameters to estimate; ``fixed`` the fixed values (the caller's, plus
    the ``known`` ones); ``known`` the values taken as known from structure.toml (fixed at
    them: a value without a sigma, or a prior's mean when its parameter is not estimated);
    ``priors`` the Gaussian priors ``name -> (mean, sigma)`` on estimated parameters.
    """

    names: tuple[str, ...]
    fixed: Mapping[str, float]
    known: Mapping[str, float]
    priors: Mapping[str, tuple[float, float]]
    source: str = "structure.toml"

    def to_dict(self) -> dict[str, Any]:
        """``known_from_structure`` (name -> value) and ``prior_from_structure`` (name ->
        mean and sigma), SI units (kg, kg m^2, m): keys of the estimate's JSON."""
        return {"known_from_structure": dict(self.known),
                "prior_from_structure": {n: {"mean": m, "sigma": s}
                                         for n, (m, s) in self.priors.items()}}

    def prior_vector(self, names: Sequence[str]) -> tuple[np.ndarray, np.ndarray] | None:
        """``(zbar, Pbar)`` over the state ``(x, y, psi, u, v, r, *names)`` for
        :func:`estimator.batch.least_squares.batch_ls`: the priors' means and variances,
        every other entry diffuse (infinite variance); None without priors on ``names``."""
        if not any(n in self.priors for n in names):
            return None
        n = 6 + len(names)
        zbar, P = np.zeros(n), np.diag(np.full(n, np.inf))
        for j, name in enumerate(names):
            if name in self.priors:
                zbar[6 + j], P[6 + j, 6 + j] = self.priors[name][0], self.priors[name][1] ** 2
        return zbar, P


def body_knowledge(structure, estimate: Sequence[str] | None,
                   fixed: Mapping[str, float]) -> BodyKnowledge:
    """The unknowns of a structure run from its ``[body]`` (partly known
    properties): a known value (no sigma, or sigma 0) is fixed, a value with a sigma is a
    Gaussian prior. ``estimate`` (None: :data:`STRUCTURE_ESTIMATE`) and ``fixed`` are the
    caller's and win: a known value named in ``estimate`` is estimated (the fit starts at
    it), one in ``fixed`` takes that value. A prior whose parameter is not estimated fixes
    it at the prior's mean. Raises UserError when nothing is left to estimate."""
    body = structure.body
    known, priors = body.known(), body.priors()
    if estimate is None:
        names = tuple(n for n in STRUCTURE_ESTIMATE if n not in fixed and n not in known)
    else:
        names = tuple(estimate)
    taken = {n: v for n, v in known.items() if n not in names and n not in fixed}
    taken.update({n: m for n, (m, _) in priors.items() if n not in names and n not in fixed})
    used = {n: priors[n] for n in names if n in priors}
    if not names:
        from_body = [n for n in STRUCTURE_ESTIMATE if n in known and n not in fixed]
        from_opt = [n for n in STRUCTURE_ESTIMATE if n in fixed]
        why = "; ".join(w for w in (
            f"[body] gives {', '.join(from_body)} as known (no sigma)" if from_body else "",
            f"--fixed gives {', '.join(from_opt)}" if from_opt else "") if w)
        raise UserError(f"{structure.source}: nothing left to estimate: {why}; name what to "
                        "estimate with --estimate (e.g. --estimate mass), or give a [body] "
                        "value a sigma to make it a prior")
    return BodyKnowledge(names, {**taken, **fixed}, taken, used, str(structure.source))
