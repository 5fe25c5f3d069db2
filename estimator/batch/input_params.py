"""Valve dead time and shared-supply drop estimated WITH the body: batch least
squares of the initial state, the plant parameters (mass, Izz, cx, cy, ...) and the input
parameters of a vehicle's thrust profile, and their Cramér-Rao bound.

Input parameters (:data:`INPUT_NAMES`): ``delay`` (s, the valves' dead time, vehicle.toml
``[valves] delay_s``), ``drop`` (one ``drop_per_valve`` shared by every supply of on/off
valves) or ``drop.<supply>`` (that supply's own). The thrust profile depends on them
through :meth:`common.vehicle.Vehicle.input_profile` (exact switching instants, so the
trajectory is smooth in both), and their Jacobian columns are central finite differences
of the propagated trajectory (forward for a delay within one step of 0; the drop enters
the thrust linearly). The plant parameters' columns are the analytic transition matrices
of :mod:`estimator.batch.ls_problem`.

The fit (:func:`fit_input_params`): today's :func:`estimator.batch.least_squares.batch_ls`
(growing horizon) at the starting input values gives the start of the plant parameters;
then damped Gauss-Newton on all unknowns together over the whole span. The reported
covariance is the JOINT one (``(J^T W J)^-1`` of every unknown at the solution): the sigma
of the mass includes what the run leaves uncertain in the delay and the drop.

Where the run does not inform an input parameter it is NOT estimated and a warning says
why: a drop when no two valves of its supply are ever open together, a delay when the
valves never open, a delay the fit drives to its bound 0 (held at 0), and either when its
sigma at the solution exceeds :data:`UNINFORMED_SIGMA` (then the fit is repeated with it
held at its start value).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from common.errors import UserError
from common.vehicle import Vehicle
from estimator.batch.crlb import (
    DEFAULT_MAX_STEP_S,
    PARAM_SCALE,
    STATE_SCALE,
    CRLBResult,
    crlb_from_fisher,
    fisher_information,
    safe_inverse,
)
from estimator.batch.least_squares import batch_ls
from estimator.batch.ls_problem import HorizonProblem, solve_scaled
from estimator.batch.ls_result import BatchResult
from estimator.plant.model import ARM_M, wrap_angle

INPUT_NAMES = ("delay", "drop")
"""The input parameters; ``drop.<supply>`` names one supply's drop."""

INPUT_SCALE = {"delay": 1e-3, "drop": 1e-2}
"""Characteristic size: s, fraction per other open valve."""

FD_STEP = {"delay": 2e-4, "drop": 1e-3}
"""Finite-difference step of each input parameter (s, fraction)."""

UNINFORMED_SIGMA = {"delay": 0.02, "drop": 0.05}
"""A sigma above this (20 ms; 5 % per valve) leaves the parameter not estimated."""

PLANT_DEFAULTS = {"arm": ARM_M, "ct": 0.0, "cr": 0.0, "kb": 0.0, "ax": 0.0, "ay": 0.0,
                  "cx": 0.0, "cy": 0.0}


def is_input_name(name: str) -> bool:
    """True for ``delay``, ``drop`` and ``drop.<supply>``."""
    return name in INPUT_NAMES or name.startswith("drop.")


def split_names(names: Sequence[str]) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """``(plant names, input names)`` of a ``--estimate`` list."""
    return (tuple(n for n in names if not is_input_name(n)),
            tuple(n for n in names if is_input_name(n)))


@dataclass(frozen=True)
class InputModel:
    """A vehicle's commands ``(cmd_t (Nc,), duty (Nc, N))`` and the input parameters
    ``names`` that shape its thrust profile."""

    vehicle: Vehicle
    cmd_t: np.ndarray
    duty: np.ndarray
    names: tuple[str, ...]

    def __post_init__(self) -> None:
        supplies = self.vehicle.onoff_supplies()
        for n in self.names:
            if not is_input_name(n):
                raise UserError(f"unknown input parameter {n!r}; choose from delay, drop, "
                                "drop.<supply>")
            if n.startswith("drop") and not supplies:
                raise UserError(f"{self.vehicle.source}: {n}: the vehicle has no on/off valves "
                                "(a thrust table states its own drop)")
            if n.startswith("drop.") and n[5:] not in supplies:
                raise UserError(f"{self.vehicle.source}: {n}: no supply {n[5:]!r} of on/off "
                                f"valves (supplies: {', '.join(supplies)})")
        if "drop" in self.names and any(n.startswith("drop.") for n in self.names):
            raise UserError("estimate either one shared drop or drop.<supply>, not both")
        if len(set(self.names)) != len(self.names):
            raise UserError(f"input parameters repeat: {', '.join(self.names)}")

    def supplies(self, name: str) -> list[str]:
        """The supplies whose drop the parameter ``name`` sets."""
        return list(self.vehicle.onoff_supplies()) if name == "drop" else [name[5:]]

    def start(self) -> np.ndarray:
        """The vehicle's own values: ``[valves] delay_s`` and its supplies' drops."""
        return np.array([self.vehicle.valves.delay_s if n == "delay"
                         else self.vehicle.drop_of(self.supplies(n)[0]) for n in self.names])

    def vehicle_at(self, theta: Sequence[float]) -> Vehicle:
        """The vehicle with the input parameters ``theta`` (in ``names`` order)."""
        delay, drops = None, {}
        for n, x in zip(self.names, theta, strict=True):
            if n == "delay":
                delay = float(x)
            else:
                drops.update({s: float(x) for s in self.supplies(n)})
        return self.vehicle.with_input_params(delay, drops)

    def profile(self, theta: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
        """The plant's held virtual thrusts ``(t, thrust (M, 4))`` at ``theta``."""
        return self.vehicle_at(theta).input_profile(self.cmd_t, self.duty)

    def uninformed(self) -> dict[str, str]:
        """``{name: why}`` of the parameters these commands cannot inform at all."""
        out = {}
        for n in self.names:
            if n == "delay":
                if not np.any(self.duty):
                    out[n] = "the valves never open"
            else:
                counts = [self.vehicle.open_counts(self.duty, s) for s in self.supplies(n)]
                if max(int(c.max(initial=0)) for c in counts) < 2:
                    out[n] = (f"no two valves of supply {', '.join(self.supplies(n))} are ever "
                              "open at the same time")
        return out


class JointProblem:
    """Residuals and Jacobian of poses against ``(z = initial state + plant parameters,
    theta = input parameters)``."""

    def __init__(self, pose_t, pose, model: InputModel, names: tuple[str, ...],
                 fixed: Mapping[str, float], w: np.ndarray, max_step: float) -> None:
        self.pose_t, self.pose, self.model = pose_t, pose, model
        self.names, self.fixed, self.w, self.max_step = names, dict(fixed), w, max_step
        self._last: tuple[bytes, HorizonProblem] | None = None

    def problem(self, theta) -> HorizonProblem:
        """The plant problem at the input parameters ``theta``. The last one is kept: the
        Jacobian at an accepted step reuses the trajectory its evaluation integrated."""
        key = np.asarray(theta, float).tobytes()
        if self._last is not None and self._last[0] == key:
            return self._last[1]
        t, thrust = self.model.profile(theta)
        prob = HorizonProblem(self.pose_t, self.pose, t, thrust, self.names, self.fixed, self.w,
                              None, None, self.max_step)
        self._last = (key, prob)
        return prob

    def evaluate(self, z, theta) -> tuple[float, np.ndarray | None]:
        cost, res, _ = self.problem(theta).evaluate(z)
        return cost, res

    def jacobian(self, z, theta) -> tuple[float, np.ndarray, np.ndarray]:
        """``(cost, residuals (N, 3), J (N, 3, 6+p+q))``: J = d predicted pose / d unknown."""
        prob = self.problem(theta)
        cost, res, states = prob.evaluate(z)
        if not math.isfinite(cost):
            raise UserError("the predicted trajectory is not finite at the current estimate")
        cols = []
        for j, n in enumerate(self.model.names):
            h = FD_STEP["delay" if n == "delay" else "drop"]
            e = np.zeros(len(theta))
            e[j] = h
            one_sided = n == "delay" and theta[j] - h < 0
            rp = self.evaluate(z, theta + e)[1]
            rm = res if one_sided else self.evaluate(z, theta - e)[1]
            cols.append(-wrap_angle(rp - rm) / (h if one_sided else 2 * h))
        H = prob.output_jacobian(z, states)
        J = np.concatenate([H, np.stack(cols, axis=-1)], axis=-1) if cols else H
        return cost, res, J

    def normal(self, J, res) -> tuple[np.ndarray, np.ndarray]:
        sig = 1.0 / np.sqrt(self.w)
        return (fisher_information(J, sig[0], sig[2]),
                np.einsum("kin,i,ki->n", J, self.w, res, optimize=True))


def _scale(names, input_names) -> np.ndarray:
    return np.concatenate([STATE_SCALE, [PARAM_SCALE[n] for n in names],
                           [INPUT_SCALE["delay" if n == "delay" else "drop"] for n in input_names]])


def _gauss_newton(jp: JointProblem, z, theta, max_iter: int, tol_sigma: float):
    """Damped Gauss-Newton on ``(z, theta)``; returns ``(z, theta, converged, Lambda,
    residuals, iterations, history)`` (Lambda at the returned point)."""
    p = len(z)
    scale = _scale(jp.names, jp.model.names)
    cost, res, J = jp.jacobian(z, theta)
    Lam, lam = jp.normal(J, res)
    history, mu, it, converged = [cost], 0.0, 0, False
    while it < max_iter:
        step = solve_scaled(Lam, lam, scale, mu)
        sig = np.sqrt(np.maximum(np.diag(safe_inverse(Lam)), 1e-300))
        z_new, th_new = z + step[:p], theta + step[p:]
        for j, n in enumerate(jp.model.names):
            if n == "delay":
                th_new[j] = max(th_new[j], 0.0)  # a dead time is not negative
        cost_new, res_new = jp.evaluate(z_new, th_new)
        if cost_new <= cost:
            # the step taken, a delay held at its bound 0 included (the unclamped step of a
            # delay pinned at 0 never shrinks: 30 wasted iterations before the re-fit
            # without it)
            taken = np.concatenate([z_new - z, th_new - theta])
            small = bool(np.max(np.abs(taken) / sig) < tol_sigma)
            z, theta, cost, it = z_new, th_new, cost_new, it + 1
            history.append(cost)
            cost, res, J = jp.jacobian(z, theta)
            Lam, lam = jp.normal(J, res)
            mu = 0.0 if mu < 1e-6 else mu / 10.0
            if small:
                converged = True
                break
        else:
            mu = 1e-4 if mu == 0.0 else mu * 10.0
            if mu > 1e10:
                break
    return z, theta, converged, Lam, res, it, history


def fit_input_params(pose_t, pose, vehicle: Vehicle, cmd_t, duty, *,
                     names: Sequence[str] = ("mass", "izz", "cx", "cy"),
                     input_names: Sequence[str] = ("delay", "drop"),
                     fixed: Mapping[str, float] | None = None,
                     initial: Mapping[str, float] | None = None,
                     input_initial: Mapping[str, float] | None = None,
                     sigma_pos_m: float = 0.01, sigma_yaw_rad: float = math.radians(1.0),
                     max_iter: int = 30, tol_sigma: float = 1e-3,
                     max_step: float = DEFAULT_MAX_STEP_S) -> BatchResult:
    """Batch LS of the initial state, the plant parameters ``names`` and the input
    parameters ``input_names`` (module doc) of a vehicle run: poses ``(pose_t, pose)``,
    commands ``(cmd_t, duty)`` in percent per thruster. ``input_initial`` the start of the
    input parameters (default the vehicle's own values). The result's ``names`` are the
    plant names then the input names ESTIMATED (an uninformed one is left out, its reason
    in ``warnings``); ``cov`` the joint covariance; ``params`` holds the input values."""
    pose_t = np.asarray(pose_t, float)
    pose = np.asarray(pose, float)
    model = InputModel(vehicle, np.asarray(cmd_t, float), np.asarray(duty, float),
                       tuple(input_names))
    theta_all = model.start()
    for k, v in (input_initial or {}).items():
        if k not in model.names:
            raise UserError(f"initial value for {k!r}, which is not estimated")
        theta_all[model.names.index(k)] = float(v)
    warnings = []
    skip = model.uninformed()
    for n, why in skip.items():
        warnings.append(f"{n} is not estimated: {why} (the run does not inform it); held at "
                        f"{theta_all[model.names.index(n)]:g}")
    names = tuple(names)
    fixed_d = {**PLANT_DEFAULTS, **{k: float(v) for k, v in (fixed or {}).items()}}
    start = batch_ls(pose_t, pose, *model.profile(theta_all), names=names, fixed=fixed_d,
                     initial=initial, sigma_pos_m=sigma_pos_m, sigma_yaw_rad=sigma_yaw_rad)
    w = np.array([sigma_pos_m**-2, sigma_pos_m**-2, sigma_yaw_rad**-2])
    z = start.z0.copy()
    while True:
        keep = tuple(n for n in model.names if n not in skip)
        sub = InputModel(model.vehicle_at(theta_all), model.cmd_t, model.duty, keep)
        jp = JointProblem(pose_t, pose, sub, names, fixed_d, w, max_step)
        theta = np.array([theta_all[model.names.index(n)] for n in keep])
        z, theta, converged, Lam, res, it, history = _gauss_newton(jp, z, theta, max_iter,
                                                                   tol_sigma)
        for n, x in zip(keep, theta, strict=True):
            theta_all[model.names.index(n)] = x
        if "delay" in keep and theta[keep.index("delay")] == 0.0:
            # pinned at its bound: the run shows no dead time it can resolve from none
            skip["delay"] = "at its bound"
            warnings.append("delay is not estimated: the fit reaches its bound 0 s (no dead time "
                            "the run can tell from none); held at 0")
            continue
        cov = safe_inverse(Lam)
        sigma = np.sqrt(np.maximum(np.diag(cov), 0.0))
        loose = [(n, s) for n, s in zip(keep, sigma[len(z):], strict=True)
                 if not s <= UNINFORMED_SIGMA["delay" if n == "delay" else "drop"]]
        if not loose:
            break
        for n, s in loose:
            skip[n] = "too little information"
            theta_all[model.names.index(n)] = model.start()[model.names.index(n)]
            warnings.append(f"{n} is not estimated: the run informs it too little (sigma "
                            f"{s:.3g} > {UNINFORMED_SIGMA['delay' if n == 'delay' else 'drop']:g});"
                            f" held at {theta_all[model.names.index(n)]:g}")
    all_names = names + keep
    zfull = np.concatenate([z, theta])
    params = {**jp.problem(theta).params(z), **dict(zip(model.names, theta_all.tolist(),
                                                          strict=True))}

    def pick(n):
        return (params[n], float(sigma[6 + all_names.index(n)]), 6 + all_names.index(n)) \
            if n in all_names else (params[n], 0.0, None)

    m, sm, im = pick("mass")
    izz, si, ii = pick("izz")
    corr = float(cov[im, ii] / (sm * si)) if im is not None and ii is not None else float("nan")
    msg = "converged" if converged else f"not converged after {it} joint iterations"
    return BatchResult(zfull, cov, sigma, all_names, params, float(pose_t[0]), pose_t, res,
                       start.iterations + it, converged, start.cost_history + history, m, izz,
                       sm, si, corr, msg, start.stages, start.elapsed_s, Lam,
                       start.warnings + warnings)


def crlb_input_params(pose_t, vehicle: Vehicle, cmd_t, duty, params: Mapping[str, float], *,
                      names: Sequence[str] = ("mass", "izz", "cx", "cy"),
                      input_names: Sequence[str] = ("delay", "drop"), s0=None,
                      sigma_pos_m: float = 0.01, sigma_yaw_rad: float = math.radians(1.0),
                      max_step: float = DEFAULT_MAX_STEP_S) -> CRLBResult:
    """The Cramér-Rao bound on ``names`` + ``input_names`` (the initial state a nuisance)
    at the plant ``params`` and the vehicle's own input values (its delay and drops: the
    truth), with the same Jacobian as :func:`fit_input_params`."""
    names = tuple(names)
    model = InputModel(vehicle, np.asarray(cmd_t, float), np.asarray(duty, float),
                       tuple(input_names))
    fixed = {**PLANT_DEFAULTS, **{k: float(v) for k, v in params.items()}}
    pose_t = np.asarray(pose_t, float)
    s0 = np.zeros(6) if s0 is None else np.asarray(s0, float)
    z = np.concatenate([s0, [fixed[n] for n in names]])
    w = np.array([sigma_pos_m**-2, sigma_pos_m**-2, sigma_yaw_rad**-2])
    jp = JointProblem(pose_t, np.zeros((len(pose_t), 3)), model, names, fixed, w, max_step)
    _, _, J = jp.jacobian(z, model.start())
    F = fisher_information(J, sigma_pos_m, sigma_yaw_rad)
    all_names = names + model.names
    M, cov, sig, logdet = crlb_from_fisher(F, all_names)
    return CRLBResult(all_names, F, M, cov, sig, logdet, len(pose_t))
