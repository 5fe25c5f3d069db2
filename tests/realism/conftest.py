"""Shared fixtures of the realism tests: simulated translate-rotate runs (paper's experiment)."""

import pytest

from estimator.report_realism import FRICTION, TRUTH
from estimator.sim import write_sim_run


@pytest.fixture(scope="package")
def run_dirs(tmp_path_factory):
    """Run folders: 'friction' (friction + yaw bias), 'tilt' (+ tilt), 'none' (frictionless)."""
    from estimator.report_realism import simulate_run

    base = tmp_path_factory.mktemp("realism")
    out = {}
    for name, truth, seed in (("friction", FRICTION, 31), ("tilt", TRUTH, 32), ("none", {}, 33)):
        res, _, _ = simulate_run(truth, seed)
        out[name] = write_sim_run(res, base / name, "translate-rotate")
    return out
