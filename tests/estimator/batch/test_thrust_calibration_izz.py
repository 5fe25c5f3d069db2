"""In-situ calibration with only the mass known (issue 24, item 4): Izz estimated with the
thrust factors (--per thruster and --per common) within 3 sigma over seeds, the mass's
uncertainty carried into both; runs that do not inform Izz refused in one line naming it;
a dead thruster and a reversed one named."""

from __future__ import annotations

import numpy as np
import pytest

from common.errors import UserError
from common.thrust_table import ThrustTable
from estimator.batch.thrust_calibration.calibrate import calibrate_thrust
from estimator.plant.inputs import translate_rotate
from estimator.plant.model import PlantParams
from estimator.plant.sim import SimConfig, simulate

EFF = ("efficiency.1", "efficiency.2", "efficiency.3", "efficiency.4")
KNOWN = PlantParams(0.72, 0.0062)


def _sim(cmd_t, duty, gains=(1.01, 0.96, 0.995, 1.0), seed=1):
    thrust = ThrustTable.default().thrust_n(duty) * np.asarray(gains)
    return simulate(cmd_t, duty, KNOWN, thrust_n=thrust, config=SimConfig(seed=seed))


def _cal(s, **kw):
    kw.setdefault("per", "thruster")
    return calibrate_thrust(s.pose_t, s.pose, s.cmd_t, s.duty_pct, ThrustTable.default(),
                            mass_kg=KNOWN.mass_kg, izz_kgm2=None, **kw)


@pytest.mark.parametrize("per,gains", [("thruster", (1.01, 0.96, 0.995, 1.0)),
                                       ("common", (1.03,) * 4)])
def test_izz_and_factors_within_3_sigma(per, gains):
    cmd_t, duty = translate_rotate(28.0)
    want = np.array(gains) if per == "thruster" else np.array(gains[:1])
    for seed in (1, 2, 3):
        r = _cal(_sim(cmd_t, duty, gains, seed), per=per, mass_sigma_kg=0.002 * KNOWN.mass_kg)
        assert r.converged and r.names == (EFF if per == "thruster" else ("scale",))
        assert np.all(np.abs(r.values - want) < 3 * r.sigma), (r.values, r.sigma)
        iz = r.izz
        assert abs(iz["izz_kgm2"] - KNOWN.izz_kgm2) < 3 * iz["izz_sigma_kgm2"], iz
        # the mass's uncertainty reaches both; the total is the root-sum-square of the parts
        assert iz["izz_sigma_mass_kgm2"] > 0 and np.all(np.diag(r.cov_mass) > 0)
        parts = [iz[f"izz_sigma_{k}_kgm2"] for k in ("noise", "mass", "table")]
        assert iz["izz_sigma_kgm2"] == pytest.approx(np.sqrt(np.sum(np.square(parts))))
        assert set(iz["izz_correlation"]) == set(r.names)
        assert all(-1 <= c <= 1 for c in iz["izz_correlation"].values())
        d = r.to_dict()
        assert set(d["factors"]) == set(r.names) and d["izz_kgm2"] == iz["izz_kgm2"]
        assert "izz_kgm2" not in d["known"] and not r.warnings


def test_common_scale_written_as_correlated_efficiencies(tmp_path):
    cmd_t, duty = translate_rotate(14.0)
    r = _cal(_sim(cmd_t, duty, (1.03,) * 4), per="common")
    new = r.new_table(ThrustTable.default())
    new.save(tmp_path / "t.toml")
    back = ThrustTable.load(tmp_path / "t.toml")
    cal = back.calibration
    assert cal.parameters == EFF
    assert np.allclose(cal.efficiency, r.values[0])
    assert np.allclose(cal.covariance, r.cov[0, 0])  # one scale: fully correlated
    assert cal.info["known"]["izz_estimated_kgm2"] == r.izz["izz_kgm2"]


def test_translation_only_run_refused_naming_izz():
    cmd_t, duty = translate_rotate(14.0)
    keep = cmd_t <= 7.0  # the translation half: pairs whose torques cancel
    s = _sim(cmd_t[keep], duty[keep], (1.0,) * 4)
    with pytest.raises(UserError, match="Izz is not identifiable from this run: it never turns") as e:
        _cal(s, per="common")
    assert "--izz" in str(e.value) and "\n" not in str(e.value)


def test_rotation_only_run_refused_naming_izz_and_scale():
    cmd_t, duty = translate_rotate(14.0)
    duty = np.where((cmd_t < 7.0)[:, None], 0.0, duty)  # at rest, then pure couples
    s = _sim(cmd_t, duty, (1.0,) * 4)
    with pytest.raises(UserError, match="Izz and scale are not identifiable together") as e:
        _cal(s, per="common")
    assert "--izz" in str(e.value)


def test_dead_thruster_named():
    cmd_t, duty = translate_rotate(28.0)
    r = _cal(_sim(cmd_t, duty, (1.0, 1.0, 0.0, 1.0)))
    dead = [w for w in r.warnings if "dead or blocked" in w.lower()]
    assert len(dead) == 1 and dead[0].startswith("thruster 3 (column d3)"), r.warnings
    assert abs(r.izz["izz_kgm2"] - KNOWN.izz_kgm2) < 3 * r.izz["izz_sigma_kgm2"]


def test_reversed_thruster_named():
    cmd_t, duty = translate_rotate(28.0)
    r = _cal(_sim(cmd_t, duty, (1.0, -1.0, 1.0, 1.0)))
    assert r.values[1] == pytest.approx(-1.0, abs=3 * r.sigma[1])
    rev = [w for w in r.warnings if "reversed or mis-wired" in w.lower()]
    assert len(rev) == 1 and rev[0].startswith("thruster 2 (column d2)"), r.warnings
