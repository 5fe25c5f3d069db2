"""Model options, Ljung-Box and the likelihood-ratio decision (fast, no fits)."""

from types import SimpleNamespace

import numpy as np
import pytest

from common.errors import UserError
from estimator.batch.model_select import decide, diagnose, ljung_box
from estimator.plant.parameter_sets import MODELS, fixed_for, model_of, names_for, resolve_names


def test_model_names_are_nested_and_mapped():
    assert names_for("ideal") == ("mass", "izz")
    assert set(names_for("ideal")) < set(names_for("friction")) < set(names_for("friction+tilt"))
    assert model_of(("izz", "mass", "kb", "cr", "ct")) == "friction"
    assert model_of(("mass", "ct")) is None
    with pytest.raises(UserError):
        names_for("viscous")


def test_fixed_for_zeroes_unestimated_extras_and_refuses_clashes():
    assert fixed_for("ideal") == {"ct": 0.0, "cr": 0.0, "kb": 0.0, "ax": 0.0, "ay": 0.0}
    assert fixed_for("friction", {"arm": 0.06}) == {"ax": 0.0, "ay": 0.0, "arm": 0.06}
    assert fixed_for("ideal", {"ct": 0.3})["ct"] == 0.3  # hand-set friction
    with pytest.raises(UserError, match="estimates ct"):
        fixed_for("friction", {"ct": 0.3})


def test_resolve_names_model_vs_estimate():
    assert resolve_names("friction", None) == MODELS["friction"]
    assert resolve_names("friction", ("mass", "izz")) == MODELS["friction"]  # the default list
    assert resolve_names(None, ("mass", "ct")) == ("mass", "ct")
    with pytest.raises(UserError, match="conflicts"):
        resolve_names("friction+tilt", ("mass", "izz", "ct"))


def test_ljung_box_white_vs_correlated():
    rng = np.random.default_rng(3)
    white = rng.normal(size=2000)
    q, p, acf = ljung_box(white, 20)
    assert p > 0.01 and acf[0] == 1.0 and len(acf) == 21
    ar = np.empty(2000)
    ar[0] = 0
    for k in range(1, 2000):
        ar[k] = 0.5 * ar[k - 1] + white[k]
    q2, p2, acf2 = ljung_box(ar, 20)
    assert p2 < 1e-10 and q2 > 10 * q and acf2[1] == pytest.approx(0.5, abs=0.06)


def _fake_fit(model, chi2_target, n=1000, converged=True, seed=0):
    """A ModelFit whose normalised residuals give exactly chi2_target."""
    rng = np.random.default_rng(seed)
    r = rng.normal(size=(n, 3))
    r *= np.sqrt(chi2_target / np.sum(r**2))
    res = SimpleNamespace(residuals=r * np.array([0.01, 0.01, 0.02]), names=MODELS[model],
                          converged=converged, mass_kg=1.0, izz_kgm2=1e-3, z0=np.zeros(13))
    return diagnose(model, res, 0.01, 0.02)


def test_decide_sequential_lr_tests():
    n_obs = 3000
    # no improvement: ideal kept
    fits = {"ideal": _fake_fit("ideal", n_obs), "friction": _fake_fit("friction", n_obs - 2),
            "friction+tilt": _fake_fit("friction+tilt", n_obs - 4)}
    s = decide(fits)
    assert s.chosen == "ideal" and "not supported" in s.reason and s.by_bic == "ideal"
    # friction helps a lot, tilt not
    fits["friction"] = _fake_fit("friction", n_obs - 200)
    fits["friction+tilt"] = _fake_fit("friction+tilt", n_obs - 201)
    s = decide(fits)
    assert s.chosen == "friction" and "friction fits significantly better" in s.reason
    assert [t.big for t in s.tests] == ["friction", "friction+tilt"]
    # tilt only: the step ideal -> friction is weak but ideal -> friction+tilt is not
    fits["friction"] = _fake_fit("friction", n_obs - 3)
    fits["friction+tilt"] = _fake_fit("friction+tilt", n_obs - 100)
    assert decide(fits).chosen == "friction+tilt"


def test_decide_scales_by_overdispersion():
    # the same LR of 60 on 3 df is decisive with chi2/dof = 1 but not with chi2/dof = 25
    n_obs = 3000
    fits = {"ideal": _fake_fit("ideal", n_obs + 60), "friction": _fake_fit("friction", n_obs)}
    assert decide(fits).chosen == "friction"
    fits = {"ideal": _fake_fit("ideal", 25 * n_obs + 60), "friction": _fake_fit("friction", 25 * n_obs)}
    s = decide(fits)
    assert s.chosen == "ideal" and any("reduced chi-square" in n for n in s.notes)
