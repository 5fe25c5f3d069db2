"""Thruster health on simulated 200 s 8-valve runs with tilt, drag and a dead time: the
dead thruster found, no false verdict on healthy runs. One seed each here (about 40 s each); the 20-seed
study is marked slow (make test-slow)."""

import math

import pytest

from estimator.shooting.health import thruster_health
from tests.estimator.shooting.simruns import sim_run, vehicle

SIG = dict(sigma_pos_m=0.003, sigma_yaw_rad=math.radians(0.3))
EFFECTS = dict(tilt=(0.002, -0.001), friction=(0.3, 0.002, 0.0), delay_s=0.05)
NAMES = ("T1", "T2", "T3", "T4", "T5", "T6", "T7", "T8")


def _verdicts(seed, dead, stuck=None):
    pt, p, ct, d = sim_run(seed, 200.0, dead=dead, stuck=stuck, **EFFECTS)
    rep = thruster_health(pt, p, vehicle(), ct, d, **SIG)
    return {t.name: t.verdict for t in rep.thrusters}


def _dead_of(seed):
    return NAMES[seed % len(NAMES)]


@pytest.mark.parametrize("seed", [11])
def test_dead_thruster_found(seed):
    v = _verdicts(seed, _dead_of(seed))
    assert {n: x for n, x in v.items() if x != "ok"} == {_dead_of(seed): "dead"}


@pytest.mark.parametrize("seed", [21])
def test_no_false_verdict_on_a_healthy_run(seed):
    assert set(_verdicts(seed, None).values()) == {"ok"}


def test_stuck_open_valve_found():
    """T4 pushes all the time while its commands open and close it: a constant wrench that
    its own explains."""
    v = _verdicts(5, None, stuck="T4")
    assert {n: x for n, x in v.items() if x != "ok"} == {"T4": "stuck-open"}


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(100, 120))
def test_twenty_seeds_dead_found(seed):
    v = _verdicts(seed, _dead_of(seed))
    assert v == {n: ("dead" if n == _dead_of(seed) else "ok") for n in NAMES}


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(200, 220))
def test_twenty_seeds_no_false_verdict(seed):
    assert set(_verdicts(seed, None).values()) == {"ok"}
