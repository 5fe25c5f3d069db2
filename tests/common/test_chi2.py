"""common.chi2 gives what scipy.stats.chi2 gives, to 1e-12 relative (the estimators use it to
skip scipy's import cost)."""

import subprocess
import sys

import numpy as np
import pytest
from scipy.stats import chi2 as reference

from common import chi2


@pytest.mark.parametrize("df", [0.5, 1, 2, 3, 4, 6, 7.5, 40, 3 * 200, 4 * 200])
def test_sf_and_ppf_equal_scipy_stats(df):
    x = np.array([1e-6, 0.1, 0.5, 1.0, 3.0, 9.49, 25.0, 200.0, 900.0])
    assert np.allclose(chi2.sf(x, df), reference.sf(x, df), rtol=1e-12, atol=0)
    p = np.array([1e-12, 1e-9, 0.001, 0.025, 0.5, 0.95, 0.975, 0.999])
    assert np.allclose(chi2.ppf(p, df), reference.ppf(p, df), rtol=1e-12, atol=0)
    assert chi2.ppf(0.975, df) == pytest.approx(reference.ppf(0.975, df), rel=1e-13)
    q = np.array([1e-15, 1e-4 / 37, 1e-4, 0.01, 0.5, 0.99])
    assert np.allclose(chi2.isf(q, df), reference.isf(q, df), rtol=1e-12, atol=0)
    assert chi2.isf(1e-4, df) == pytest.approx(reference.isf(1e-4, df), rel=1e-13)
    assert isinstance(chi2.ppf(0.975, df), float) and isinstance(chi2.sf(3.0, df), float)


def test_edges():
    assert chi2.sf(0.0, 3) == 1.0 and chi2.sf(-2.0, 3) == 1.0
    assert list(chi2.sf(np.array([-1.0, 0.0]), 2)) == [1.0, 1.0]
    assert chi2.ppf(0.0, 4) == 0.0 and chi2.ppf(1.0, 4) == np.inf
    with pytest.raises(ValueError):
        chi2.ppf(1.5, 4)
    with pytest.raises(ValueError):
        chi2.isf(-0.1, 4)


def test_no_scipy_import():
    # the point of the module: a tpods command that needs a chi-square limit loads no scipy
    code = "import sys, common.chi2; sys.exit('scipy' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0
