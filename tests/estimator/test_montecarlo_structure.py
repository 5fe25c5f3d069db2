"""Monte Carlo of batch LS on a structure (issue 18: tpods estimate montecarlo --structure)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.stats import chi2

from common.structure import Body, Module, Structure
from estimator.montecarlo_structure import (
    NAMES,
    UNITS,
    StructureMcConfig,
    run_structure_montecarlo,
)
from tests.support.cli import run_in_process

TRI = Structure("tri", (Module("a", (-0.25, 0.0), 0.0), Module("b", (0.25, 0.05), 90.0),
                        Module("c", (0.0, 0.3), 45.0)),
                Body(mass_kg=2.6, izz_kgm2=0.065, com_m=(0.02, 0.045)))


def test_batch_ls_on_a_structure_is_consistent_over_runs():
    """30 runs of a three-module structure (m, Izz +/- 30 %, centre of mass +/- 3 cm around
    its [body] values, 5 % drops): the fit's reported sigma matches the spread of its errors
    and the NEES of (m, Izz, cx, cy) its chi-square law."""
    cfg = StructureMcConfig(TRI, runs=30, spread=0.3, com_spread_m=0.03, duration_s=20.0,
                            pose_rate_hz=60.0, drop=0.05, seed=4)
    res = run_structure_montecarlo(cfg)
    s = res.summary()
    assert s["runs_converged"] == 30 and not res.messages
    # the truths really vary around the start
    start = TRI.initial_guess()
    assert np.ptp(res.truth[:, 0]) > 0.3 * start["mass"] and np.ptp(res.truth[:, 2]) > 0.03
    for n in NAMES:
        assert abs(s[f"bias_{n}_sigmas"]) < 3.5, n
        assert 0.6 < s[f"std_over_sigma_{n}"] < 1.45, (n, s[f"std_over_sigma_{n}"])
        assert 0.7 < s[f"std_normalised_{n}"] < 1.35, (n, s[f"std_normalised_{n}"])
        assert s[f"rms_sigma_{n}_{UNITS[n]}"] >= s[f"mean_sigma_{n}_{UNITS[n]}"] > 0
        assert s[f"within_3sigma_{n}"] >= 0.9 and s[f"within_2sigma_{n}"] >= 0.8, n
    assert s["nees_mean_inside"], (s["nees_mean"], s["nees_mean_bounds_95"])
    lo, hi = s["nees_mean_bounds_95"]
    assert (lo, hi) == pytest.approx(tuple(chi2.ppf([0.025, 0.975], 4 * 30) / 30))
    cols, data = res.runs_table()
    assert cols[1:5] == ["truth_mass", "truth_izz", "truth_cx", "truth_cy"]
    assert np.mean(data[:, cols.index("nees")]) == pytest.approx(s["nees_mean"], rel=1e-12)


def test_montecarlo_structure_cli(tpods_exe, tmp_path):
    (tmp_path / "tri.toml").write_text(
        'name = "tri"\n[[modules]]\nname = "a"\nposition_m = [-0.25, 0.0]\n[[modules]]\n'
        'name = "b"\nposition_m = [0.25, 0.05]\nyaw_deg = 90\n[[modules]]\nname = "c"\n'
        "position_m = [0.0, 0.3]\nyaw_deg = 45\n")
    r = run_in_process("estimate", "montecarlo", "--structure", str(tmp_path / "tri.toml"),
            "--runs", "4", "--duration", "15", "--pose-rate", "60", "--drop", "0.05",
            "--noise-pos", "0.005", "--seed", "2", "--out", str(tmp_path / "mc"), "--json")
    assert r.returncode == 0, r.stderr
    s = json.loads(r.stdout)
    assert s["runs_converged"] == 4 and s["estimated"] == ["mass", "izz", "cx", "cy"]
    assert s["std_mass_kg"] > 0 and s["mean_sigma_cx_m"] > 0
    saved = json.loads((tmp_path / "mc" / "montecarlo.json").read_text())
    assert saved["summary"] == s and saved["config"]["noise_pos_m"] == 0.005
    assert saved["config"]["modules"] == 3
    rows = np.loadtxt(tmp_path / "mc" / "runs.csv", delimiter=",", skiprows=1)
    assert rows.shape == (4, 15) and np.all(rows[:, -1] == 1)
    text = run_in_process("estimate", "montecarlo", "--structure", str(tmp_path / "tri.toml"),
               "--runs", "2", "--duration", "10", "--pose-rate", "60")
    assert text.returncode == 0 and "NEES (4 dof)" in text.stdout and "cx" in text.stdout
    bad = run_in_process("estimate", "montecarlo", "--noise-pos", "0.005", "--runs", "2")
    assert bad.returncode == 2 and "--noise-pos is for --structure" in bad.stderr
    assert "Traceback" not in bad.stderr
