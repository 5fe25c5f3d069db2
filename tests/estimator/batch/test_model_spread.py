"""Model uncertainty and unphysical signs (issue 24, real runs): the sign rules of
:mod:`estimator.batch.physical_signs`, the counting and ranges of
:mod:`estimator.batch.model_spread`, and on a simulated eight-thruster vehicle run ``--model
auto`` whose candidates agree: no spread warning, every candidate counted."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from estimator.batch.model_spread import candidate_rows, spread
from estimator.batch.physical_signs import sign_warnings, unphysical

ROOT = Path(__file__).resolve().parents[3]


def test_negative_damping_beyond_three_sigma_is_named():
    names = ("mass", "izz", "ct", "cr", "kb", "drop.main")
    vals = {"mass": 1.0, "izz": 0.01, "ct": -0.05, "cr": -0.001, "kb": -3.0, "drop.main": -0.2}
    sig = {"mass": 0.1, "izz": 0.001, "ct": 0.01, "cr": 0.001, "kb": 0.1, "drop.main": 0.01}
    bad = unphysical(names, vals, sig)
    assert set(bad) == {"ct", "drop.main"}  # cr within 3 sigma of 0; kb may be negative
    lines = sign_warnings(names, vals, sig)
    assert lines[0].startswith("ct = -0.05 +- 0.01 (5.0 sigma below 0): negative linear damping")
    assert "not physical" in lines[1] and "drop.main" in lines[1]


def _fit(mass, sm, converged=True, ct=0.0, sct=1.0):
    res = SimpleNamespace(names=("mass", "izz", "ct"), mass_kg=mass, mass_sigma_kg=sm,
                          izz_kgm2=0.3, izz_sigma_kgm2=0.003, converged=converged,
                          params={"mass": mass, "izz": 0.3, "ct": ct},
                          z0=np.zeros(9), sigma=np.r_[np.zeros(6), sm, 0.003, sct])
    return SimpleNamespace(result=res)


def test_only_converged_physical_fits_count():
    fits = {"ideal": _fit(35.0, 0.6), "friction": _fit(22.8, 0.13, ct=-1.3, sct=0.05),
            "friction+tilt": _fit(22.6, 0.2, converged=False)}
    doc, warn = spread(candidate_rows(fits), {"mass_kg": 0.2, "izz_kgm2": 0.003})
    assert doc["counted"] == ["ideal"]
    assert doc["mass_kg_range"] == [22.6, 35.0] and doc["mass_kg_range_over"] == "all candidates"
    assert warn and warn[0].startswith("the mass depends on the model: 22.6..35 kg")
    assert "friction: ct = -1.3 < 0" in warn[0] and "friction+tilt: not converged" in warn[0]
    # two counted fits apart by more than their sigmas: the range over them
    fits = {"ideal": _fit(22.3, 0.2), "friction": _fit(23.0, 0.2)}
    doc, warn = spread(candidate_rows(fits), {"mass_kg": 0.2})
    assert doc["counted"] == ["ideal", "friction"] and doc["mass_kg_exceeds_sigma"]
    assert warn[0].startswith("the mass depends on the model: 22.3..23 kg across ideal 22.3, "
                              "friction 23, more than its sigma 0.2 kg")
    # within their sigmas: nothing said
    doc, warn = spread(candidate_rows({"ideal": _fit(23.0, 0.3), "friction": _fit(23.2, 0.3)}),
                       {"mass_kg": 0.3})
    assert not doc["mass_kg_exceeds_sigma"] and not warn


def test_simulated_vehicle_models_agree_and_nothing_is_said(tpods_exe, tmp_path):
    out = tmp_path / "run"
    r = subprocess.run([tpods_exe, "sim", "--vehicle", str(ROOT / "vehicles/example-8-onoff.toml"),
                        "--input", "pulses", "--mass", "23.09", "--izz", "0.31", "--duration",
                        "40", "--seed", "3", "--out", str(out)], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    r = subprocess.run([tpods_exe, "estimate", "batch", str(out), "--model", "auto", "--json"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    est = json.loads(r.stdout)
    fits = est["model_selection"]["fits"]
    assert fits["ideal"]["start"].startswith("started from a scan")
    assert fits["friction+tilt"]["start"] == "warm start at the friction optimum"
    spread_doc = est["model_spread"]
    assert spread_doc["counted"] == ["ideal", "friction", "friction+tilt"]
    lo, hi = spread_doc["mass_kg_range"]
    assert hi - lo < 0.25 * est["mass_sigma_kg"]
    assert not spread_doc["mass_kg_exceeds_sigma"] and not spread_doc["izz_kgm2_exceeds_sigma"]
    assert not any("depends on the model" in w or "not physical" in w
                   for w in est.get("warnings", []))
    assert "depends on the model" not in r.stderr
