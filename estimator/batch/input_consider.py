"""The total sigma of the joint valve fit: what the vehicle's STATED force
uncertainty adds to :func:`estimator.batch.input_params.fit_input_params` (the body, the
valve dead time and the supply drop estimated together).

The consider parameters are the vehicle's own (:meth:`common.vehicle.Vehicle.input_sensitivity`
at the estimated delay and drops): every on/off valve's ``force_sigma_n``
(``<thruster>:force``), a table's uncertainty, and a supply's ``drop_sigma``
(``<supply>:drop``) unless that drop is estimated (then it is an unknown, not a considered
parameter). As for one module (:mod:`estimator.batch.consider`): the estimate moves by
``S dc`` with ``S = Lambda^-1 sum_k H_k^T W J_k``, ``H_k`` the joint fit's Jacobian at its
solution (the same one as its covariance, finite-difference columns of the delay and drop
included) and ``J_k`` the poses' response to the considered parameters; the thrust part of
the covariance is ``S P_c S^T`` and the total the noise part plus it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from common.thrust_uncertainty import ThrustSensitivity
from common.vehicle import Vehicle
from estimator.batch.consider import ConsiderResult, consider, considered_output
from estimator.batch.crlb import DEFAULT_MAX_STEP_S
from estimator.batch.input_params import PLANT_DEFAULTS, InputModel, JointProblem, is_input_name
from estimator.batch.ls_result import BatchResult


def unestimated_terms(sens: ThrustSensitivity, supplies: Sequence[str]) -> ThrustSensitivity:
    """``sens`` without the ``<supply>:drop`` columns of the ``supplies`` whose drop is
    estimated."""
    drop = {f"{s}:drop" for s in supplies}
    keep = [i for i, n in enumerate(sens.names) if n not in drop]
    return ThrustSensitivity(sens.thrust_n, sens.jacobian[..., keep],
                             tuple(sens.names[i] for i in keep),
                             sens.covariance[np.ix_(keep, keep)])


def joint_consider(res: BatchResult, pose, vehicle: Vehicle, cmd_t, duty,
                   input_names: Sequence[str], *, fixed: Mapping[str, float] | None = None,
                   sigma_pos_m: float, sigma_yaw_rad: float,
                   max_step: float = DEFAULT_MAX_STEP_S) -> ConsiderResult | None:
    """The considered part of the joint fit ``res`` (of ``fit_input_params(res.t, pose,
    vehicle, cmd_t, duty, input_names=input_names, fixed=fixed)``) at its solution; None
    when the vehicle states no uncertainty that reaches these commands (or the fit left a
    direction without information)."""
    if not np.all(np.isfinite(res.sigma)):
        return None
    cmd_t, duty = np.asarray(cmd_t, float), np.asarray(duty, float)
    model = InputModel(vehicle, cmd_t, duty, tuple(input_names))
    at = model.vehicle_at([res.params[n] for n in model.names])
    plant = tuple(n for n in res.names if not is_input_name(n))
    cov_noise = res.cov if res.cov_noise is None else res.cov_noise
    return consider_at(at, res.t, pose, cmd_t, duty, plant, res.z0, fixed, cov_noise,
                       sigma_pos_m=sigma_pos_m, sigma_yaw_rad=sigma_yaw_rad, max_step=max_step,
                       input_names=tuple(n for n in res.names if is_input_name(n)))


def consider_at(vehicle: Vehicle, pose_t, pose, cmd_t, duty, plant: Sequence[str], z,
                fixed: Mapping[str, float] | None, cov_noise: np.ndarray, *,
                input_names: Sequence[str], sigma_pos_m: float, sigma_yaw_rad: float,
                max_step: float = DEFAULT_MAX_STEP_S) -> ConsiderResult | None:
    """The considered part at ``z`` = (initial state, ``plant`` values, ``input_names``
    values) of ``vehicle`` (its delay and drops at those values) with the noise covariance
    ``cov_noise`` (the fit's, or a bound's inverse Fisher matrix); None without a stated
    uncertainty that reaches the commands ``(cmd_t, duty)``."""
    cmd_t, duty = np.asarray(cmd_t, float), np.asarray(duty, float)
    model = InputModel(vehicle, cmd_t, duty, tuple(input_names))
    sens_t, sens = vehicle.input_sensitivity(cmd_t, duty)
    sens = unestimated_terms(sens, [s for n in model.names if n.startswith("drop")
                                    for s in model.supplies(n)])
    if sens.empty:
        return None
    w = np.array([sigma_pos_m**-2, sigma_pos_m**-2, sigma_yaw_rad**-2])
    fixed_d = {**PLANT_DEFAULTS, **{k: float(v) for k, v in (fixed or {}).items()}}
    jp = JointProblem(np.asarray(pose_t, float), np.asarray(pose, float), model, tuple(plant),
                      fixed_d, w, max_step)
    z = np.asarray(z, float)
    z, theta = z[:6 + len(plant)], z[6 + len(plant):]
    _, _, H = jp.jacobian(z, theta)
    params = jp.problem(theta).params(z)
    J = considered_output(pose_t, sens_t, sens, params, z[:6], max_step)
    return consider(H, w, cov_noise, J, sens.covariance, sens.names)
