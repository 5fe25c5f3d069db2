"""A diagnosis of "no net force" or "no torque" is said from the commands and the geometry,
never from where a fit stopped: a fit that ends with an infinite sigma on a run full of
force and torque is reported as a failed fit."""

import math

import numpy as np

from estimator.batch.plausibility import no_information

INF = np.array([0, 0, 0, 0, 0, 0, math.inf, math.inf])


def test_forces_and_torques_in_the_commands_blame_the_fit():
    thrust = np.array([[0.2, 0.0, 0.0, 0.0], [0.0, 0.0, 0.3, 0.0], [0.0, 0.0, 0.0, 0.0]])
    why = no_information(("mass", "izz"), INF, thrust)
    assert "the fit diverged, not the run" in why and "--segments auto" in why
    assert "no net force" not in why and "no torque" not in why


def test_a_run_without_torque_still_says_so():
    thrust = np.array([[0.2, 0.2, 0.0, 0.0], [0.0, 0.0, 0.2, 0.2]])  # T1+T2, T3+T4: no moment
    why = no_information(("mass", "izz"), INF, thrust)
    assert "izz: no torque" in why and "mass:" not in why


def test_no_thrust_at_all():
    assert "no thrust" in no_information(("mass", "izz"), INF, np.zeros((3, 4)))
