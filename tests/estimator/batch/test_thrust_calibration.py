"""In-situ thrust calibration (issue 17, item 4): factors recovered within 3 sigma on simulated
runs of a known body, degenerate runs refused, the factor derivatives against central
differences, the written table, and the "simulated pairs": a known body calibrates a table
with one weak nozzle, an unknown body is then measured with the nominal and the calibrated
table (its total sigma carrying the calibration covariance)."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from common.errors import UserError
from common.runfolder import Run
from common.thrust_table import ThrustTable
from common.thrust_uncertainty import ThrustUncertainty
from estimator.batch.calibration_design import evaluate_calibration, gated_sine, search_calibration
from estimator.batch.consider import output_sensitivity, segment_jacobian
from estimator.batch.crlb import make_grid, reference_states
from estimator.batch.design import DesignSettings
from estimator.batch.least_squares import estimate_run
from estimator.batch.thrust_calibration.calibrate import (
    absorbed_terms,
    calibrate_thrust,
    factor_jacobian,
    with_factors,
)
from estimator.plant.inputs import phase_sine, translate_rotate
from estimator.plant.model import PlantParams
from estimator.plant.sim import SimConfig, simulate

EFF = ("efficiency.1", "efficiency.2", "efficiency.3", "efficiency.4")
TRUE_EFF = (1.01, 0.96, 0.995, 1.0)  # nozzle 2 is 4 % weak
KNOWN = PlantParams(0.72, 0.0062)    # the paper's 14 s experiment's module
UNKNOWN = PlantParams(1.6, 0.0135)
# a designed calibration input (tpods design --for thrust-calibration, 30 s, paper's module):
# every nozzle count 1..4 occurs
GATED = dict(amplitude_pct=20.08, omega_rad_s=0.501, mean_pct=20.2,
             phases_rad=(3.402, 1.883, 2.656, 0.478), low_pct=10.0)


def _table(scale_rel: float = 0.0) -> ThrustTable:
    t = ThrustTable.default()
    return replace(t, uncertainty=ThrustUncertainty(scale_rel)) if scale_rel else t


def _sim(cmd_t, duty, plant, eff=TRUE_EFF, seed=1, nscale=None):
    truth = with_factors(ThrustTable.default(), EFF, eff)
    if nscale:
        truth = with_factors(truth, tuple(f"nozzle_scale.{k}" for k in nscale), tuple(nscale.values()))
    return simulate(cmd_t, duty, plant, thrust_n=truth.thrust_n(duty), config=SimConfig(seed=seed))


def test_efficiencies_recovered_within_3_sigma():
    cmd_t, duty = translate_rotate(42.0)
    for seed in (1, 2):
        s = _sim(cmd_t, duty, KNOWN, seed=seed)
        r = calibrate_thrust(s.pose_t, s.pose, s.cmd_t, s.duty_pct, _table(), mass_kg=KNOWN.mass_kg,
                             izz_kgm2=KNOWN.izz_kgm2, per="thruster")
        assert r.converged and r.names == EFF
        z = (r.values - np.array(TRUE_EFF)) / r.sigma
        assert np.all(np.abs(z) < 3), z
        assert np.all(r.sigma < 0.01)  # noise only: known m and Izz exact
        assert np.allclose(r.cov, r.cov_noise)


def test_known_value_uncertainty_is_carried_and_limits():
    cmd_t, duty = translate_rotate(28.0)
    s = _sim(cmd_t, duty, KNOWN)
    r = calibrate_thrust(s.pose_t, s.pose, s.cmd_t, s.duty_pct, _table(), mass_kg=KNOWN.mass_kg,
                         izz_kgm2=KNOWN.izz_kgm2, mass_sigma_kg=0.002 * KNOWN.mass_kg,
                         izz_sigma_kgm2=0.01 * KNOWN.izz_kgm2)
    b = r.budget()
    for n in EFF:
        assert b[n]["izz"] > b[n]["noise"]  # a 1 % Izz dominates a 28 s run
        assert b[n]["total"] == pytest.approx(math.sqrt(sum(b[n][k] ** 2 for k in
                                                            ("noise", "mass", "izz", "table"))))
    assert set(r.limited_by().values()) == {"known Izz uncertainty"}
    # a known Izz 1 % high: the efficiencies move as the consider sensitivity says
    r2 = calibrate_thrust(s.pose_t, s.pose, s.cmd_t, s.duty_pct, _table(), mass_kg=KNOWN.mass_kg,
                          izz_kgm2=1.01 * KNOWN.izz_kgm2)
    r0 = calibrate_thrust(s.pose_t, s.pose, s.cmd_t, s.duty_pct, _table(), mass_kg=KNOWN.mass_kg,
                          izz_kgm2=KNOWN.izz_kgm2)
    shift = np.abs(r2.values - r0.values)
    predicted = np.sqrt(np.diag(r.cov_izz))
    assert np.allclose(shift, predicted, rtol=0.05)


def test_nozzle_scales_and_both_on_a_designed_input():
    cmd_t, duty = gated_sine(30.0, 50.0, **GATED)
    plant = PlantParams(2.268, 3.78e-3)
    s = _sim(cmd_t, duty, plant, nscale={1: 1.0, 2: 0.98, 3: 1.0, 4: 1.03})
    r = calibrate_thrust(s.pose_t, s.pose, s.cmd_t, s.duty_pct, _table(), mass_kg=plant.mass_kg,
                         izz_kgm2=plant.izz_kgm2, per="both")
    ref = r.reference_count
    assert ref in (1, 2, 3, 4) and f"nozzle_scale.{ref}" not in r.names
    truth_ns = {1: 1.0, 2: 0.98, 3: 1.0, 4: 1.03}
    # with the reference count's scale fixed at 1, the efficiencies carry its level
    want = {n: TRUE_EFF[int(n[-1]) - 1] * truth_ns[ref] for n in EFF}
    want.update({f"nozzle_scale.{k}": v / truth_ns[ref] for k, v in truth_ns.items() if k != ref})
    z = np.array([(v - want[n]) / sg for n, v, sg in zip(r.names, r.values, r.sigma, strict=True)])
    assert np.all(np.abs(z) < 3), dict(zip(r.names, z, strict=True))
    rn = calibrate_thrust(s.pose_t, s.pose, s.cmd_t, s.duty_pct, _table(), mass_kg=plant.mass_kg,
                          izz_kgm2=plant.izz_kgm2, per="nozzles")
    assert rn.names == tuple(f"nozzle_scale.{k}" for k in (1, 2, 3, 4))


def test_never_opened_thruster_refused():
    cmd_t, duty = translate_rotate(14.0)
    duty = duty.copy()
    duty[:, 3] = 0.0
    s = _sim(cmd_t, duty, KNOWN)
    with pytest.raises(UserError, match="thruster 4 is never opened"):
        calibrate_thrust(s.pose_t, s.pose, s.cmd_t, s.duty_pct, _table(), mass_kg=0.72,
                         izz_kgm2=0.0062, per="thruster")


@pytest.mark.parametrize("inp,k", [("sine", 4), ("tr", 2)])
def test_single_count_confounds_both(inp, k):
    cmd_t, duty = phase_sine(20.0) if inp == "sine" else translate_rotate(14.0)
    s = _sim(cmd_t, duty, KNOWN)
    with pytest.raises(UserError, match=rf"nozzle_scale\.{k} with the common level of the "
                                        r"efficiencies \(efficiency\.1, efficiency\.2, efficiency\.3, "
                                        r"efficiency\.4\)") as e:
        calibrate_thrust(s.pose_t, s.pose, s.cmd_t, s.duty_pct, _table(), mass_kg=0.72,
                         izz_kgm2=0.0062, per="both")
    assert "smallest eigenvalue" in str(e.value) and "\n" not in str(e.value)


def test_factor_derivatives_match_central_differences():
    cmd_t, duty = gated_sine(6.0, 50.0, **GATED)
    t = np.arange(0, 6.0, 1 / 60)
    table = with_factors(_table(), ("efficiency.2", "nozzle_scale.3"), (0.97, 1.02))
    names = ("efficiency.2", "nozzle_scale.3")
    params = {"mass": 0.72, "izz": 0.0062}
    s0 = np.array([0.1, -0.2, 0.3, 0.01, 0.0, 0.05])
    thrust, fjac = factor_jacobian(table, duty, names)
    grid = make_grid(cmd_t, thrust, t)
    J = output_sensitivity(reference_states(s0, grid, params), grid, params,
                           segment_jacobian(grid, fjac))
    for i, n in enumerate(names):
        v = 0.97 if i == 0 else 1.02
        h = 1e-5
        pose = []
        for d in (+h, -h):
            tt = with_factors(table, (n,), (v + d,)).thrust_n(duty)
            g = make_grid(cmd_t, tt, t)
            pose.append(reference_states(s0, g, params)[g.node_pos, :3])
        fd = (pose[0] - pose[1]) / (2 * h)
        assert np.max(np.abs(J[..., i] - fd)) < 1e-6 * np.max(np.abs(fd)) + 1e-12


def test_new_table_round_trip_and_absorbed_scale(tmp_path):
    table = _table(scale_rel=0.01)
    assert absorbed_terms(table, EFF) == ("scale",)
    assert absorbed_terms(table, ("nozzle_scale.2",)) == ()  # other counts keep the scale error
    cmd_t, duty = translate_rotate(14.0)
    s = _sim(cmd_t, duty, KNOWN)
    r = calibrate_thrust(s.pose_t, s.pose, s.cmd_t, s.duty_pct, table, mass_kg=0.72,
                         izz_kgm2=0.0062, mass_sigma_kg=1.4e-3, izz_sigma_kgm2=6e-5)
    assert r.absorbed == ("scale",) and np.all(r.cov_table == 0)
    new = r.new_table(table, run="runs/cal")
    path = tmp_path / "cal.toml"
    new.save(path)
    back = ThrustTable.load(path)
    assert back.coefficients == table.coefficients
    assert back.calibration.parameters == EFF
    assert np.allclose(back.calibration.efficiency, r.values)
    assert np.allclose(back.calibration.covariance, r.cov)
    info = back.calibration.info
    assert info["source"] == "tpods calibrate thrust" and info["run"] == "runs/cal"
    assert info["known"]["mass_kg"] == 0.72 and info["known"]["izz_sigma_kgm2"] == 6e-5
    assert back.uncertainty.scale_rel == 0 and "calibrated away" in back.uncertainty.notes
    # the coefficient covariance (not absorbed) would stay; here the table has none
    assert back.states_uncertainty


def test_simulated_pairs_unknown_body_error_shrinks():
    """Known body (0.72 kg) on translate-rotate calibrates per-thruster efficiencies; the
    unknown body (1.6 kg) shares them (nozzle 2 4 % weak)."""
    rng = np.random.default_rng(5)
    sm, si = 0.002 * KNOWN.mass_kg, 0.01 * KNOWN.izz_kgm2  # balance +-2.5 g, bifilar 1 %
    cmd_t, duty = translate_rotate(42.0)
    s = _sim(cmd_t, duty, KNOWN, seed=11)
    r = calibrate_thrust(s.pose_t, s.pose, s.cmd_t, s.duty_pct, _table(),
                         mass_kg=KNOWN.mass_kg + sm * rng.normal(),
                         izz_kgm2=KNOWN.izz_kgm2 + si * rng.normal(),
                         mass_sigma_kg=sm, izz_sigma_kgm2=si)
    calibrated = r.new_table(_table())
    u = _sim(cmd_t, duty, UNKNOWN, seed=12)
    run = Run(Path("sim"), u.cmd_t, u.duty_pct, u.pose_t, u.pose)
    nominal = estimate_run(run, _table())
    cal = estimate_run(run, calibrated)
    assert cal.converged and "in-situ calibration" in cal.thrust_note
    assert cal.cov_thrust is not None and np.all(cal.sigma_thrust[6:] > 0)
    for res, big in ((nominal, True), (cal, False)):
        zm = (res.mass_kg - UNKNOWN.mass_kg) / res.mass_sigma_kg
        zi = (res.izz_kgm2 - UNKNOWN.izz_kgm2) / res.izz_sigma_kgm2
        if big:
            assert max(abs(zm), abs(zi)) > 20
            assert abs(res.mass_kg / UNKNOWN.mass_kg - 1) > 0.05
        else:
            assert abs(zm) < 3 and abs(zi) < 3, (zm, zi)
            assert abs(res.mass_kg / UNKNOWN.mass_kg - 1) < 0.02
            assert abs(res.izz_kgm2 / UNKNOWN.izz_kgm2 - 1) < 0.03


def test_design_for_calibration_prefers_mixed_counts():
    st = DesignSettings(duration_s=20.0)
    tab = _table()
    sine = evaluate_calibration(*phase_sine(20.0), tab, st, per="both")
    assert not sine.feasible and "confounded" in sine.reason
    d = search_calibration(tab, st, per="both", n_random=6, n_refine=0)
    assert d.best.feasible and len(d.best.counts_s) >= 2
    lo, hi = tab.duty_range
    open_ = d.best.duty_pct[d.best.duty_pct > 0]
    assert np.all((open_ >= lo) & (open_ <= hi))


def test_kept_factors_and_friction_model():
    """A table already calibrated per thruster, re-calibrated per nozzle count: the kept
    efficiencies stay with their covariance, and the cross-covariance is negative (a kept
    level stated too high makes the fit lower the nozzle scale); --model friction fits."""
    cmd_t, duty = translate_rotate(14.0)
    s = _sim(cmd_t, duty, KNOWN)
    kw = dict(mass_kg=0.72, izz_kgm2=0.0062, mass_sigma_kg=1.4e-3, izz_sigma_kgm2=6e-5)
    first = calibrate_thrust(s.pose_t, s.pose, s.cmd_t, s.duty_pct, _table(), **kw)
    cal = first.new_table(_table())
    r = calibrate_thrust(s.pose_t, s.pose, s.cmd_t, s.duty_pct, cal, per="nozzles",
                         model="friction", **kw)
    assert r.converged and set(r.extras) == {"ct", "cr", "kb"}
    assert r.kept_names == EFF and np.all(r.kept_cross < 0)
    assert r.values[0] == pytest.approx(1.0, abs=3 * r.sigma[0])  # the level is in the kept effs
    new = r.new_table(cal)
    assert new.calibration.parameters == ("nozzle_scale.2", *EFF)
    assert np.allclose(new.calibration.efficiency, cal.calibration.efficiency)
    assert np.min(np.linalg.eigvalsh(new.calibration.covariance)) > -1e-12
