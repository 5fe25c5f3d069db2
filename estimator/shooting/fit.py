"""A run fitted as shooting segments: the use case on arrays (:func:`fit_segments`).

The shared parameters are estimated over every segment at once, each segment from its own
initial state (:mod:`estimator.shooting.problem`, :mod:`estimator.shooting.solve`). The
segment length is the caller's, or chosen from the data (:func:`choose_length`): the
longest of :data:`CANDIDATE_LENGTHS_S` whose fit still describes the poses within
:data:`LENGTH_RMS_RATIO` times the 2 s fit's misfit (a clean run gets long
segments, close to single shooting; a real run with unmodelled forces short ones). Stretches where
the model cannot hold are excluded and named (:mod:`estimator.shooting.events`).

Sigma of each shared parameter, all reported:

- ``noise``: the stated pose noise alone, white residuals assumed;
- ``clustered``: the segment-clustered sandwich (correlated model error within a segment),
  scaled by t_{G-1}(0.975)/1.96 for G segments (:func:`t_scale`);
- ``thrust``: the vehicle's stated force uncertainty (``force_sigma_n``) of every thruster
  whose efficiency is not estimated, considered at the solution;
- ``total``: sqrt(clustered^2 + thrust^2): what the output promises. With fewer than
  :data:`MIN_CLUSTERS` segments (or twice the shared parameters) a clustered covariance is
  itself too uncertain; the total then takes the larger of it and the noise sigma scaled
  by the residuals' rms over the stated noise (at least 1), and a note says so.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from common.errors import UserError
from common.vehicle import Vehicle
from estimator.shooting.events import find_events, outlier_segments
from estimator.shooting.inputs import ThrustChannels, vehicle_channels
from estimator.shooting.problem import GLOBAL_NAMES, LOG_NAMES, ShootingProblem, default_value
from estimator.shooting.segments import SegmentPlan, plan_segments
from estimator.shooting.solve import covariances, levenberg_marquardt, reduce_normal, safe_inv
from estimator.shooting.start import equation_error_start

CANDIDATE_LENGTHS_S = (2.0, 3.0, 5.0, 8.0, 12.0, 20.0, 30.0)
"""Segment lengths the automatic choice tries, s."""

BASE_LENGTH_S = 2.0
"""Segments short enough for any table's model error: the automatic choice starts here."""

LENGTH_RMS_RATIO = 1.25
"""A longer segment length is taken while its residual rms stays within this factor of the
2 s fit's: longer segments carry more information (fewer free
initial states) as long as the model still holds over them."""


@dataclass
class SegmentFit:
    """The result of :func:`fit_segments` (sklearn style: read-only after the fit).

    ``values``/``sigma``: shared parameter name -> value (SI) / sigma by term
    (``{"noise", "clustered", "thrust", "total"}``); ``residuals`` (n, 3) m, m, rad at
    ``t`` (n,) with ``segment`` (n,) of each; ``segment_rms`` (S, 3).
    """

    names: tuple[str, ...]
    values: dict[str, float]
    sigma: dict[str, dict[str, float]]
    cov: dict[str, np.ndarray]
    plan: SegmentPlan
    converged: bool
    message: str
    iterations: int
    t: np.ndarray
    residuals: np.ndarray
    segment: np.ndarray
    segment_rms: np.ndarray
    elapsed_s: float
    length_note: str = ""
    sigma_note: str = ""
    warnings: list[str] = field(default_factory=list)
    s0: np.ndarray | None = field(default=None, repr=False)
    theta: np.ndarray | None = field(default=None, repr=False)

    def rms(self) -> np.ndarray:
        return np.sqrt(np.mean(self.residuals ** 2, axis=0))

    def to_dict(self) -> dict:
        return {
            "method": "ls-segments", "converged": self.converged, "message": self.message,
            "iterations": self.iterations, "elapsed_s": self.elapsed_s,
            "segments": {"n": self.plan.n, "length_s": self.plan.length_s,
                         "how": self.length_note, "dropped_short": self.plan.dropped,
                         "breaks": [{"t": t, "why": w} for t, w in self.plan.breaks]},
            "excluded": [{"t0": a, "t1": b, "why": w} for a, b, w in self.plan.excluded],
            "params": {n: {"value": self.values[n], **self.sigma[n]} for n in self.names},
            "sigma_terms": self.sigma_note or (
                "total = sqrt(clustered^2 + thrust^2); clustered: segment-clustered sandwich "
                "(model error correlated within a segment); thrust: the vehicle's stated force "
                "uncertainty; not included: the spread across models (compare --model "
                "choices) and a time base that is not the poses' capture times"),
            "rms_residuals": {"x_m": float(self.rms()[0]), "y_m": float(self.rms()[1]),
                              "yaw_rad": float(self.rms()[2])},
            "warnings": list(self.warnings),
        }


def _theta0(names: Sequence[str], initial: Mapping[str, float], fixed: Mapping[str, float]):
    out = []
    for n in names:
        v = float(initial.get(n, fixed.get(n, default_value(n))))
        if n in LOG_NAMES:
            if not v > 0:
                raise UserError(f"initial {n} must be positive, got {v:g}")
            v = math.log(v)
        out.append(v)
    return np.array(out)


def _solve(pose_t, pose, plan, ch, names, fixed, sigma, theta, s0=None, max_iter=60):
    prob = ShootingProblem(pose_t, pose, plan, ch, names, fixed, sigma)
    if s0 is None:
        vals = prob.values(theta[None])
        s0 = prob.initial_states(float(vals["cx"][0]), float(vals["cy"][0]))
    return prob, levenberg_marquardt(prob, s0, theta, max_iter=max_iter)


def _states_at(prob: ShootingProblem, lm, starts: np.ndarray) -> np.ndarray | None:
    """(len(starts), 6) the fitted trajectory's states at pose indices ``starts`` (None when
    a start lies in no segment of ``prob``)."""
    states = prob.states_at_obs(lm.s0[None], lm.theta[None])[0]
    row_of = np.full(len(prob.pose_t), -1)
    row_of[prob.obs] = np.arange(len(prob.obs))
    if np.any(row_of[starts] < 0):
        return None
    return states[row_of[starts]]


def choose_length(pose_t, pose, ch, names, fixed, sigma, theta, exclude,
                  max_iter: int = 60, min_segments: int = 1) -> tuple[float, str, tuple]:
    """The longest candidate length whose fit still describes the poses as well as the
    shortest segments do: residual rms at most :data:`LENGTH_RMS_RATIO` times the 2 s fit's
    (not the stated noise: a lab's stated noise is often far above its tracker's). Each
    candidate starts from the shorter one's solution; none leaves fewer than
    ``min_segments``. Returns ``(length, how it was chosen, (problem, fit) at it)``."""
    plan = plan_segments(pose_t, pose, BASE_LENGTH_S, exclude)
    best = _solve(pose_t, pose, plan, ch, names, fixed, sigma, theta, None, max_iter)
    base_rms = math.sqrt(best[1].cost / len(best[1].r))
    limit = LENGTH_RMS_RATIO * base_rms
    chosen, seen = BASE_LENGTH_S, [f"{BASE_LENGTH_S:g} s: {base_rms:.2f}"]
    for L in CANDIDATE_LENGTHS_S[1:]:
        plan = plan_segments(pose_t, pose, L, exclude)
        if plan.n == best[0].plan.n or plan.n < min_segments:
            break  # no stretch is longer (nothing changes), or too few segments left
        s0 = _states_at(*best, plan.bounds[:, 0])
        trial = _solve(pose_t, pose, plan, ch, names, fixed, sigma, best[1].theta, s0, max_iter)
        rms = math.sqrt(trial[1].cost / len(trial[1].r)) if math.isfinite(trial[1].cost) else math.inf
        seen.append(f"{L:g} s: {rms:.2f}")
        if not (rms <= limit and trial[1].converged):
            break
        chosen, best = L, trial
    note = (f"chosen from the data: the longest segments whose residual rms stays within "
            f"{LENGTH_RMS_RATIO:g} x the {BASE_LENGTH_S:g} s fit's (in noise units: "
            f"{', '.join(seen)})")
    return chosen, note, best


def thrust_consider(prob: ShootingProblem, lm, ch: ThrustChannels, names: Sequence[str],
                    fixed: Mapping[str, float]) -> np.ndarray:
    """(p, p) covariance of the shared parameters from the stated force sigma of every
    thruster whose efficiency is not estimated (and not marked dead), at the solution."""
    extra = [f"eff.{n}" for i, n in enumerate(ch.names)
             if ch.force_sigma_n[i] > 0 and ch.opens[i] > 0 and f"eff.{n}" not in names
             and float(fixed.get(f"eff.{n}", 1.0)) != 0.0]
    p = len(names)
    if not extra:
        return np.zeros((p, p))
    ext = ShootingProblem(prob.pose_t, prob.pose, prob.plan, ch, tuple(names) + tuple(extra),
                          fixed, prob.sigma)
    theta = np.concatenate([lm.theta, [float(fixed.get(e, 1.0)) for e in extra]])
    r, Js, Jg = ext.jacobian(lm.s0, theta)
    schur = reduce_normal(ext, r, Js, Jg).schur
    A, B = schur[:p, :p], schur[:p, p:]
    sens = -safe_inv(A) @ B  # d theta / d efficiency of each considered thruster
    eff_sigma = np.array([ch.force_sigma_n[ch.names.index(e[4:])] / ch.force_n[ch.names.index(e[4:])]
                          for e in extra])
    return sens @ np.diag(eff_sigma ** 2) @ sens.T


def start_values(vehicle: Vehicle, pose_t, pose, ch: ThrustChannels, initial: Mapping[str, float],
                 fixed: Mapping[str, float]) -> dict[str, float]:
    """The start: ``initial``, else the vehicle's stated [body], else the equation error's
    mass and Izz (:func:`estimator.shooting.start.equation_error_start`), else the vehicle's
    guess."""
    body = {k: v for k, v in (("mass", vehicle.body.mass_kg), ("izz", vehicle.body.izz_kgm2))
            if v is not None}
    need = {"mass", "izz"} - set(initial) - set(fixed) - set(body)
    eq = equation_error_start(pose_t, pose, ch) if need else {}
    if "mass" in fixed and "izz" in eq and "mass" in eq:
        eq["izz"] *= float(fixed["mass"]) / eq["mass"]  # the same scale as the held mass
    return {**vehicle.initial_guess(), **eq, **body, **dict(initial)}


def fit_segments(pose_t, pose, vehicle: Vehicle, cmd_t, duty_pct, *,
                 names: Sequence[str], fixed: Mapping[str, float] | None = None,
                 initial: Mapping[str, float] | None = None, sigma_pos_m: float = 0.01,
                 sigma_yaw_rad: float = math.radians(1.0), length_s: float | None = None,
                 exclude: Sequence[tuple[float, float]] = (), find_stretches: bool = True,
                 clamp: bool = False, max_iter: int = 60, min_segments: int = 1) -> SegmentFit:
    """Fit the shared parameters ``names`` of a vehicle run by multiple shooting.

    Args:
        pose_t: (N,) s; pose: (N, 3) tracked x, y (m), yaw (rad).
        vehicle: the thrusters (:class:`common.vehicle.Vehicle`); a thruster's
            ``eff.<name>`` in ``fixed`` scales its stated thrust (0: dead).
        cmd_t, duty_pct: (Nc,), (Nc, N) the commands.
        names: estimated shared parameters (problem.GLOBAL_NAMES, ``eff.<thruster>``,
            ``bias.fx``, ``bias.fy``, ``bias.mz``).
        length_s: segment length, s (None: :func:`choose_length`, keeping at least
            ``min_segments``; inf: single shooting).
        exclude: user ranges ``(t0, t1)`` in the poses' seconds, left out.
        find_stretches: also exclude the stretches :func:`find_events` finds, and segments
            whose residuals burst far above the others' (then fitted again without them).
    """
    t_start = time.perf_counter()
    fixed = dict(fixed or {})
    initial = dict(initial or {})
    names = tuple(names)
    if not names or len(set(names)) != len(names):
        raise UserError(f"names must be distinct, got {names}")
    thrusters = [t.name for t in vehicle.thrusters]
    for n in names:
        if n.startswith("eff.") and n.split(".", 1)[1] not in thrusters:
            raise UserError(f"{n}: the vehicle has no thruster {n.split('.', 1)[1]!r}")
        if not n.startswith("eff.") and n not in GLOBAL_NAMES:
            raise UserError(f"{n}: not a parameter of the segment fit (one of "
                            f"{', '.join(GLOBAL_NAMES)} or eff.<thruster>)")
    sigma = np.array([sigma_pos_m, sigma_pos_m, sigma_yaw_rad])
    if not np.all(sigma > 0):
        raise UserError("measurement sigmas must be positive")
    pose_t = np.asarray(pose_t, float)
    pose = np.asarray(pose, float)
    ch = vehicle_channels(vehicle, cmd_t, duty_pct, clamp=clamp)
    initial = start_values(vehicle, pose_t, pose, ch, initial, fixed)
    excl = [(a, b, "excluded by the user (--exclude)") for a, b in exclude]
    if find_stretches:
        excl += find_events(pose_t, pose, np.asarray(cmd_t, float), np.asarray(duty_pct, float))
    theta = _theta0(names, initial, fixed)
    note = "set by the caller"
    if length_s is None:
        length_s, note, (prob, lm) = choose_length(pose_t, pose, ch, names, fixed, sigma, theta,
                                                   excl, max_iter, min_segments)
    else:
        plan = plan_segments(pose_t, pose, length_s, excl)
        prob, lm = _solve(pose_t, pose, plan, ch, names, fixed, sigma, theta, None, max_iter)
    if find_stretches and math.isfinite(length_s):
        bursts = outlier_segments(prob, lm)
        if bursts:
            excl += bursts
            plan = plan_segments(pose_t, pose, length_s, excl)
            prob, lm = _solve(pose_t, pose, plan, ch, names, fixed, sigma, lm.theta, None, max_iter)
    return _result(prob, lm, ch, names, fixed, note, t_start)


MIN_CLUSTERS = 10
"""Fewer segments than this (or than twice the shared parameters): the total sigma is the
larger of the clustered one and the noise sigma inflated by the residuals' misfit."""


NO_CLUSTERS = 4
"""Fewer segments than this: the clustered covariance is left out of the total."""


def t_scale(n_clusters: int) -> float:
    """``t_{G-1}(0.975) / z(0.975)``: the factor that makes a clustered sigma from G
    segments promise at 2 sigma what a t interval with G - 1 degrees of freedom does."""
    from scipy.stats import norm, t

    if n_clusters < 2:
        return math.inf
    return float(t.ppf(0.975, n_clusters - 1) / norm.ppf(0.975))


def _result(prob: ShootingProblem, lm, ch, names, fixed, note, t_start) -> SegmentFit:
    cov = covariances(prob, lm)
    cov["thrust"] = thrust_consider(prob, lm, ch, names, fixed)
    few = prob.n_seg < max(MIN_CLUSTERS, 2 * len(names))
    # few clusters: the sandwich is itself uncertain; its promise at 2 sigma is a Student t
    # with G - 1 degrees of freedom (Cameron and Miller's small-G practice), so the
    # clustered sigma is scaled by t_{G-1}(0.975) / z(0.975)
    cov["clustered"] = cov["clustered"] * t_scale(prob.n_seg) ** 2
    if few:
        inflate = max(1.0, lm.cost / max(len(lm.r) - len(names) - 6 * prob.n_seg, 1))
        # below NO_CLUSTERS segments a clustered covariance cannot be estimated at all
        base = (cov["noise"] * inflate if prob.n_seg < NO_CLUSTERS
                else np.maximum(cov["noise"] * inflate, cov["clustered"]))
    else:
        base = cov["clustered"]
    cov["total"] = base + cov["thrust"]
    vals = prob.values(lm.theta[None])
    values, sigma = {}, {}
    for j, n in enumerate(names):
        v = float(vals[n][0])
        d = v if n in LOG_NAMES else 1.0  # log coordinates: sigma of v = v sigma(log v)
        values[n] = v
        sigma[n] = {k: float(d * math.sqrt(max(c[j, j], 0.0))) for k, c in cov.items()}
    res = lm.r.reshape(-1, 3) * prob.sigma
    seg = prob.seg
    seg_rms = np.sqrt(np.stack([np.bincount(seg, res[:, k] ** 2, prob.n_seg) /
                                np.bincount(seg, minlength=prob.n_seg) for k in range(3)], 1))
    fit = SegmentFit(names, values, sigma, cov, prob.plan, lm.converged, lm.message,
                     lm.iterations, prob.pose_t[prob.obs], res, seg, seg_rms,
                     time.perf_counter() - t_start, note, s0=lm.s0, theta=lm.theta)
    fit.warnings += _misfit(fit, prob.sigma)
    tables = [t for t in getattr(ch, "tables", ()) if t.states_uncertainty]
    if tables:
        fit.sigma_note = ("the thrust table's stated uncertainty is NOT in this sigma (the fit "
                          "by segments carries on/off valves' force_sigma_n only)")
    if few:
        how = ("the noise sigma scaled by the residuals over the stated noise"
               if prob.n_seg < NO_CLUSTERS else "the larger of it and the noise sigma scaled by "
               "the residuals over the stated noise")
        note = f"{prob.n_seg} segments are too few for a clustered sigma alone: the total takes {how}"
        fit.sigma_note = f"{fit.sigma_note}; {note}" if fit.sigma_note else note
    return fit


def _misfit(fit: SegmentFit, sigma: np.ndarray) -> list[str]:
    """A warning when the residuals are far above the stated noise, with the likely causes."""
    ratio = fit.rms() / sigma
    if np.max(ratio) <= 3.0:
        return []
    return [f"the segment fit does not fit the run: residual rms {ratio[0]:.1f}x, "
            f"{ratio[1]:.1f}x, {ratio[2]:.1f}x the stated noise (x, y, yaw); likely causes: an "
            "unmodelled force (tilt, drag, a tether, a hand), a thruster that does not give its "
            "stated force (--thruster-health), a valve dead time, or a pose time base that is "
            "not the poses' capture times; the clustered sigma counts this misfit"]
