"""A vehicle that says nothing of its mass (issue 24): batch LS scans for a start
(estimator/estimate/vehicle_start.py) and converges on a 23 kg body."""

from __future__ import annotations

from common.vehicle import Vehicle
from estimator.estimate import estimate_run
from tests.estimator.batch.test_vehicle_fit import EIGHT, TRUTH, exact_forces, simulate_vehicle


def test_a_heavy_vehicle_without_a_start_is_found_by_the_scan(tmp_path):
    run_dir = simulate_vehicle(exact_forces(Vehicle.load(EIGHT)), tmp_path / "r", 5, duration_s=40.0)
    est = estimate_run(run_dir, None, estimate=None).to_dict()
    assert est["converged"], est["message"]
    assert est["start"].startswith("started from a scan of the first 10 s")
    assert abs(est["mass_kg"] - TRUTH["mass"]) < 3.5 * est["mass_sigma_kg"]
    assert abs(est["izz_kgm2"] - TRUTH["izz"]) < 3.5 * est["izz_sigma_kgm2"]
