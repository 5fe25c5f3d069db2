"""``--model auto`` for the segment fit: the model chosen by its prediction error on held-out
segments (k-fold cross-validation over segments), not by its in-sample cost.

For each fold, the shared parameters are fitted on the other folds' segments; each held-out
segment's initial state is then fitted on its first half with those parameters held, and
the model predicts its second half. The candidate with the smallest held-out rms (in noise
units) is chosen. Every candidate's held-out error is reported, and the mass and Izz of the
candidates that predict about as well as the best (within :data:`COMPARABLE`) give the
model spread: where it exceeds the chosen fit's sigma, it is added to the total.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from estimator.shooting.fit import SegmentFit, _theta0, fit_segments, start_values
from estimator.shooting.inputs import vehicle_channels
from estimator.shooting.problem import ShootingProblem
from estimator.shooting.segments import SegmentPlan, plan_segments
from estimator.shooting.solve import levenberg_marquardt

CANDIDATES = {"ideal": (), "tilt": ("ax", "ay"), "friction": ("ct", "cr"),
              "friction+tilt": ("ct", "cr", "ax", "ay")}
FOLDS = 3
COMPARABLE = 1.10
"""Candidates whose held-out rms is within this factor of the best's count for the spread."""


@dataclass
class Selection:
    chosen: str
    heldout_rms: dict[str, float]
    fits: dict[str, SegmentFit]
    spread: dict[str, tuple[float, float]]

    def to_dict(self) -> dict:
        return {"chosen": self.chosen, "heldout_rms_noise_units": self.heldout_rms,
                "by": f"{FOLDS}-fold cross-validation over segments",
                "spread": {k: {"min": a, "max": b} for k, (a, b) in self.spread.items()},
                "candidates": {n: {k: f.values[k] for k in ("mass", "izz") if k in f.values}
                               for n, f in self.fits.items()}}


def _subplan(plan: SegmentPlan, keep: np.ndarray) -> SegmentPlan:
    return replace(plan, bounds=plan.bounds[keep])


def heldout_rms(pose_t, pose, ch, plan: SegmentPlan, names, fixed, sigma, theta) -> float:
    """rms (noise units) of the predicted second halves of ``plan``'s segments, each from a
    state fitted on its first half with the shared parameters ``theta`` held."""
    half = np.column_stack([plan.bounds[:, 0], (plan.bounds[:, 0] + plan.bounds[:, 1]) // 2])
    ok = half[:, 1] - half[:, 0] >= 6
    if not ok.any():
        return math.nan
    first = replace(plan, bounds=half[ok])
    held = {**fixed, **{n: float(v[0]) for n, v in
                        ShootingProblem(pose_t, pose, first, ch, names, fixed, sigma)
                        .values(theta[None]).items() if n in names}}
    prob = ShootingProblem(pose_t, pose, first, ch, (), held, sigma)
    lm = levenberg_marquardt(prob, prob.initial_states(float(held.get("cx", 0.0)),
                                                       float(held.get("cy", 0.0))), np.zeros(0))
    whole = replace(plan, bounds=plan.bounds[ok])
    pred = ShootingProblem(pose_t, pose, whole, ch, (), held, sigma)
    r = pred.residuals(lm.s0, np.zeros(0))[0].reshape(-1, 3)
    second = np.concatenate([np.arange(m - a, b - a) + off for (a, b), m, off in
                             zip(whole.bounds, half[ok, 1], np.concatenate(
                                 [[0], np.cumsum(np.diff(whole.bounds, axis=1)[:, 0])[:-1]]),
                                 strict=True)])
    return float(np.sqrt(np.mean(r[second] ** 2))) if np.all(np.isfinite(r[second])) else math.inf


def select_model(pose_t, pose, vehicle, cmd_t, duty_pct, *, base: Sequence[str],
                 fixed: Mapping[str, float], initial: Mapping[str, float], sigma_pos_m: float,
                 sigma_yaw_rad: float, length_s: float | None, exclude=(),
                 candidates: Mapping[str, tuple[str, ...]] = CANDIDATES) -> Selection:
    """Fit every candidate (``base`` + its parameters) on the whole run, cross-validate each
    over segments, and choose (module doc)."""
    sigma = np.array([sigma_pos_m, sigma_pos_m, sigma_yaw_rad])
    fits, scores = {}, {}
    for name, extra in candidates.items():
        names = tuple(base) + tuple(n for n in extra if n not in base and n not in fixed)
        fits[name] = fit_segments(pose_t, pose, vehicle, cmd_t, duty_pct, names=names,
                                  fixed=fixed, initial=initial, sigma_pos_m=sigma_pos_m,
                                  sigma_yaw_rad=sigma_yaw_rad, length_s=length_s,
                                  exclude=exclude)
    # one plan for every candidate: the richest model's (its length describes the run)
    richest = max(fits.values(), key=lambda f: len(f.names))
    plan = plan_segments(pose_t, pose, richest.plan.length_s,
                         [(a, b, w) for a, b, w in richest.plan.excluded])
    ch = vehicle_channels(vehicle, cmd_t, duty_pct)
    fold = np.arange(plan.n) % FOLDS
    for name, f in fits.items():
        start = {**start_values(vehicle, pose_t, pose, ch, initial, fixed), **f.values}
        theta = _theta0(f.names, start, fixed)
        err, cnt = 0.0, 0
        for k in range(FOLDS):
            train, test = _subplan(plan, fold != k), _subplan(plan, fold == k)
            prob = ShootingProblem(pose_t, pose, train, ch, f.names, fixed, sigma)
            vals = prob.values(theta[None])
            lm = levenberg_marquardt(prob, prob.initial_states(float(vals["cx"][0]),
                                                               float(vals["cy"][0])), theta)
            e = heldout_rms(pose_t, pose, ch, test, f.names, fixed, sigma, lm.theta)
            if math.isfinite(e):
                err += e * e
                cnt += 1
        scores[name] = math.sqrt(err / cnt) if cnt else math.inf
    chosen = min(scores, key=lambda n: (scores[n], len(fits[n].names)))
    best = scores[chosen]
    close = [n for n, s in scores.items() if s <= COMPARABLE * best]
    spread = {}
    for k in ("mass", "izz"):
        vals = [fits[n].values[k] for n in close if k in fits[n].values]
        if len(vals) > 1:
            spread[k] = (float(min(vals)), float(max(vals)))
    return Selection(chosen, scores, fits, spread)
