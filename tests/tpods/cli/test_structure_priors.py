"""Partly known structures (issue 18, §2-3): a structure.toml [body] value without a sigma
(or with sigma 0) is known, fixed by ``tpods estimate batch|crlb``; with a sigma it is a
Gaussian prior (batch LS, the CRLB, the filters' start). ``--estimate`` wins; nothing left
to estimate is one error line. ``tpods sim --com`` gives the truth without [body]."""

import json

import numpy as np
import pytest

from common.errors import UserError
from estimator.batch.least_squares import _as_prior
from tests.support.cli import run_in_process
from tests.support.structures import TRUSS_TOML as MODULES

TRUE_MASS_KG, TRUE_IZZ_KGM2, TRUE_COM_M = 1.6, 0.03, (0.03, 0.0)
TRUTH = ("--mass", repr(TRUE_MASS_KG), "--izz", repr(TRUE_IZZ_KGM2),
         f"--com={TRUE_COM_M[0]!r},{TRUE_COM_M[1]!r}")


def _one_line_error(r):
    assert r.returncode == 2 and "Traceback" not in r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("tpods: error: "), r.stderr
    return lines[0]


def _toml(folder, name, body=""):
    path = folder / f"{name}.toml"
    path.write_text(MODULES + (f"[body]\n{body}" if body else ""))
    return str(path)


@pytest.fixture(scope="module")
def sim(tpods_exe, tmp_path_factory):
    """A 40 s two-module run (truth from the options) and its data-only estimate and bound."""
    d = tmp_path_factory.mktemp("priors")
    bare = _toml(d, "bare")
    r = run_in_process("sim", "--structure", bare, *TRUTH, "--duration", "40", "--pose-rate", "60",
            "--seed", "7", "--out", str(d / "run"))
    assert r.returncode == 0, r.stderr
    est = json.loads(run_in_process("estimate", "batch", str(d / "run"), "--json").stdout)
    bound = json.loads(run_in_process("estimate", "crlb", str(d / "run"), "--json").stdout)
    assert est["converged"] and est["estimated"] == ["mass", "izz", "cx", "cy"]
    assert est["known_from_structure"] == {} and est["prior_from_structure"] == {}
    return {"dir": d, "run": str(d / "run"), "est": est, "bound": bound}


def _batch(tpods_exe, sim, structure, *extra):
    r = run_in_process("estimate", "batch", sim["run"], "--structure", structure, "--json", *extra)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


def test_sim_takes_the_truth_from_com_and_keeps_the_users_file(sim):
    truth = json.loads((sim["dir"] / "run" / "run.json").read_text())["truth"]
    assert (truth["mass_kg"], truth["izz_kgm2"], truth["cx"], truth["cy"]) == (
        TRUE_MASS_KG, TRUE_IZZ_KGM2, *TRUE_COM_M)
    assert "[body]" not in (sim["dir"] / "run" / "structure.toml").read_text()


def test_a_known_mass_is_fixed_and_the_rest_is_no_less_certain(tpods_exe, sim):
    known = _toml(sim["dir"], "known", f"mass_kg = {TRUE_MASS_KG!r}\n")
    est = _batch(tpods_exe, sim, known)
    assert est["converged"] and est["estimated"] == ["izz", "cx", "cy"]
    assert est["known_from_structure"] == {"mass": TRUE_MASS_KG}
    assert est["mass_kg"] == TRUE_MASS_KG and est["mass_sigma_kg"] == 0.0
    free = sim["est"]
    # no larger (the two covariances are taken at slightly different estimates: 1e-3 rel.)
    for key in ("izz_sigma_kgm2", "com_x_sigma_m", "com_y_sigma_m"):
        assert 0 < est[key] <= free[key] * (1 + 1e-3), (key, est[key], free[key])
    # mass and Izz are correlated in this run: knowing the mass sharpens Izz
    assert abs(free["corr_mass_izz"]) > 0.2
    assert est["izz_sigma_kgm2"] < 0.99 * free["izz_sigma_kgm2"]
    for key, sig, true in (("izz_kgm2", "izz_sigma_kgm2", TRUE_IZZ_KGM2),
                           ("com_x_m", "com_x_sigma_m", TRUE_COM_M[0])):
        assert abs(est[key] - true) < 3.5 * est[sig], (key, est[key], est[sig])
    # sigma 0 is known too; the bound drops the known mass the same way
    zero = _toml(sim["dir"], "zero", f"mass_kg = {TRUE_MASS_KG!r}\nmass_sigma_kg = 0\n")
    assert _batch(tpods_exe, sim, zero)["estimated"] == ["izz", "cx", "cy"]
    c = run_in_process("estimate", "crlb", sim["run"], "--structure", known, "--json")
    assert c.returncode == 0, c.stderr
    bound = json.loads(c.stdout)
    assert bound["estimated"] == ["izz", "cx", "cy"] and bound["known_from_structure"] == {"mass": 1.6}
    assert bound["crlb_izz_sigma_kgm2"] < sim["bound"]["crlb_izz_sigma_kgm2"]
    assert est["izz_sigma_kgm2"] == pytest.approx(bound["crlb_izz_sigma_kgm2"], rel=0.10)
    text = run_in_process("estimate", "batch", sim["run"], "--structure", known)
    assert "known from structure.toml [body] (fixed, not estimated): mass 1.6" in text.stdout


@pytest.mark.parametrize("ratio", [0.5, 1.0, 2.0])
def test_a_prior_combines_with_the_data(tpods_exe, sim, ratio):
    """Prior sigma = ratio x the data-only sigma: the posterior information is the sum of
    the two (a Gaussian, nearly linear problem), for the estimate and for the bound."""
    s_data = sim["est"]["mass_sigma_kg"]
    s_prior = ratio * s_data
    prior = _toml(sim["dir"], f"prior{ratio}",
                  f"mass_kg = {TRUE_MASS_KG!r}\nmass_sigma_kg = {s_prior!r}\n")
    est = _batch(tpods_exe, sim, prior)
    assert est["converged"] and est["estimated"] == ["mass", "izz", "cx", "cy"]
    assert est["prior_from_structure"] == {"mass": {"mean": TRUE_MASS_KG, "sigma": s_prior}}
    assert est["known_from_structure"] == {}
    s_post = est["mass_sigma_kg"]
    assert s_post < s_prior and s_post < s_data
    assert s_post**-2 == pytest.approx(s_prior**-2 + s_data**-2, rel=0.10)
    assert abs(est["mass_kg"] - TRUE_MASS_KG) < 3.5 * s_post
    c = run_in_process("estimate", "crlb", sim["run"], "--structure", prior, "--json")
    bound = json.loads(c.stdout)
    b_data = sim["bound"]["crlb_mass_sigma_kg"]
    assert bound["crlb_mass_sigma_kg"] ** -2 == pytest.approx(s_prior**-2 + b_data**-2, rel=1e-6)
    assert bound["prior_from_structure"]["mass"]["sigma"] == s_prior


def test_a_centre_of_mass_prior_and_the_filters_start(tpods_exe, sim):
    """com_sigma_m makes cx, cy priors; ls-ekf starts from them and says so."""
    s_prior = 2e-4
    prior = _toml(sim["dir"], "com", f"com_m = [{TRUE_COM_M[0]!r}, {TRUE_COM_M[1]!r}]\n"
                                     f"com_sigma_m = {s_prior!r}\n")
    est = _batch(tpods_exe, sim, prior)
    assert set(est["prior_from_structure"]) == {"cx", "cy"}
    for key in ("com_x_sigma_m", "com_y_sigma_m"):
        assert est[key] < min(s_prior, sim["est"][key])
        assert est[key] ** -2 == pytest.approx(s_prior**-2 + sim["est"][key] ** -2, rel=0.10)
    f = _batch(tpods_exe, sim, prior, "--method", "ls-ekf")
    assert not f["diverged"] and set(f["prior_from_structure"]) == {"cx", "cy"}
    assert f["com_x_sigma_m"] < s_prior
    text = run_in_process("estimate", "batch", sim["run"], "--structure", prior, "--method", "ls-ekf")
    assert text.returncode == 0, text.stderr
    assert "prior from structure.toml [body] (in the estimate): cx 0.03 +/- 0.0002" in text.stdout


def test_estimate_names_a_known_value_and_wins(tpods_exe, sim):
    everything = _toml(sim["dir"], "all", f"mass_kg = {TRUE_MASS_KG!r}\nizz_kgm2 = 0.031\n"
                                          f"com_m = [{TRUE_COM_M[0]!r}, {TRUE_COM_M[1]!r}]\n")
    est = _batch(tpods_exe, sim, everything, "--estimate", "mass")
    assert est["estimated"] == ["mass"] and est["mass_sigma_kg"] > 0
    assert est["known_from_structure"] == {"izz": 0.031, "cx": TRUE_COM_M[0], "cy": TRUE_COM_M[1]}
    assert est["izz_kgm2"] == 0.031 and "mass 1.6" in est["start"]
    # --fixed wins over [body] too
    est = _batch(tpods_exe, sim, everything, "--estimate", "mass,cx,cy", "--fixed", "izz=0.03")
    assert est["izz_kgm2"] == 0.03 and est["known_from_structure"] == {}
    assert abs(est["mass_kg"] - TRUE_MASS_KG) < 3.5 * est["mass_sigma_kg"]


def test_nothing_left_to_estimate_is_one_line(tpods_exe, sim):
    everything = _toml(sim["dir"], "all2", "mass_kg = 1.6\nizz_kgm2 = 0.03\ncom_m = [0.03, 0]\n")
    for cmd in ("batch", "crlb"):
        line = _one_line_error(run_in_process("estimate", cmd, sim["run"], "--structure",
                                   everything))
        assert "nothing left to estimate" in line and "[body] gives mass, izz, cx, cy as known" in line
        assert "--estimate" in line
    known = _toml(sim["dir"], "known2", "mass_kg = 1.6\n")
    line = _one_line_error(run_in_process("estimate", "batch", sim["run"], "--structure", known,
                               "--fixed", "izz=0.03,cx=0.03,cy=0"))
    assert "--fixed gives izz, cx, cy" in line
    # the filters estimate mass and izz: a known mass is refused naming the way out
    line = _one_line_error(run_in_process("estimate", "batch", sim["run"], "--structure", known,
                               "--method", "ekf"))
    assert "mass known from" in line and "--estimate izz,cx,cy,mass" in line


def test_sim_com_needs_a_structure_and_body_stays_the_fallback_truth(tpods_exe, sim, tmp_path):
    line = _one_line_error(run_in_process("sim", "--com", "0.01,0", "--duration", "5",
                               "--out", str(tmp_path / "o")))
    assert "--com" in line and "--structure" in line
    body = _toml(tmp_path, "body", "mass_kg = 1.7\nizz_kgm2 = 0.04\ncom_m = [0.02, 0.01]\n")
    r = run_in_process("sim", "--structure", body, "--duration", "5", "--out", str(tmp_path / "r"))
    assert r.returncode == 0, r.stderr
    truth = json.loads((tmp_path / "r" / "run.json").read_text())["truth"]
    assert (truth["mass_kg"], truth["izz_kgm2"], truth["cx"], truth["cy"]) == (1.7, 0.04, 0.02, 0.01)
    # the copy is the user's file as given, and the sim says what estimate will make of it
    assert "com_m" in (tmp_path / "r" / "structure.toml").read_text()
    assert "tpods estimate fixes mass = 1.7, izz = 0.04, cx = 0.02, cy = 0.01 (known)" in r.stdout


def test_prior_entries_with_infinite_variance_carry_no_information():
    P = np.diag([np.inf] * 6 + [0.01**2, np.inf])
    zbar, info = _as_prior((np.zeros(8), P), 8)
    expected = np.zeros((8, 8))
    expected[6, 6] = 1e4
    np.testing.assert_allclose(info, expected, rtol=1e-12)
    P[6, 7] = P[7, 6] = 1e-6  # correlated with a diffuse entry: not a prior
    with pytest.raises(UserError, match="infinite variance"):
        _as_prior((np.zeros(8), P), 8)
