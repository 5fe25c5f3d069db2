"""Structure runs (issue 18) beyond the default batch fit: the filters' structure keys,
friction and tilt models on structures, degenerate runs refused naming what they cannot
determine."""

import json
from pathlib import Path

import pytest

from tests.support.cli import run

FIXTURE = Path(__file__).resolve().parents[3] / "runs" / "fixtures" / "structure-run"


@pytest.mark.parametrize("extra", [(), ("--fixed", "cx=0.03")])
def test_ls_ekf_json_has_the_structure_keys(tpods_exe, extra):
    """--method ls-ekf gives com_x_m, com_y_m, izz_origin_kgm2 (+ sigmas) and structure like
    --method ls: the filter's final mean and covariance; sigma 0 for a fixed value."""
    r = run(tpods_exe, "estimate", "batch", str(FIXTURE), "--method", "ls-ekf", "--json", *extra)
    assert r.returncode == 0, r.stderr
    f = json.loads(r.stdout)
    assert f["structure"] == "truss" and not f["diverged"]
    p, s = f["params"], f["sigmas"]
    if extra:
        assert "cx" not in p and f["com_x_m"] == 0.03 and f["com_x_sigma_m"] == 0.0
    else:
        assert f["com_x_m"] == p["cx"] and f["com_x_sigma_m"] == s["cx"] > 0
        assert abs(f["com_x_m"] - 0.03) < 3.5 * s["cx"]
    assert f["com_y_m"] == p["cy"] and f["com_y_sigma_m"] == s["cy"] > 0
    m, izz, cx, cy = f["mass_kg"], f["izz_kgm2"], f["com_x_m"], f["com_y_m"]
    assert f["izz_origin_kgm2"] == pytest.approx(izz + m * (cx * cx + cy * cy), rel=1e-12)
    # Izz about the origin is no better known than Izz about the centre of mass and m c^2
    assert f["izz_sigma_kgm2"] * 0.5 < f["izz_origin_sigma_kgm2"] < 10 * f["izz_sigma_kgm2"]
    assert f["com_x_error_m"] == pytest.approx(cx - 0.03, abs=1e-15)
    text = run(tpods_exe, "estimate", "batch", str(FIXTURE), "--method", "ls-ekf", *extra)
    assert text.returncode == 0, text.stderr
    assert "centre of mass (+0.030" in text.stdout and "Izz about the tracked origin" in text.stdout
