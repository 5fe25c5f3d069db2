"""Composite bodies: parallel-axis theorem against hand calculations."""

from pathlib import Path

import numpy as np
import pytest

from calibration.composite import Part, combine, load_parts
from common.errors import UserError

EXAMPLE = Path(__file__).resolve().parents[2] / "calibration" / "examples" / "truss_two_modules.toml"


def test_two_modules_and_a_rod_by_hand():
    parts = [Part("A", 0.72, 1.2e-3, -0.4, 0.0), Part("B", 0.72, 1.2e-3, 0.4, 0.0),
             Part("rod", 0.10, 0.10 * 0.6**2 / 12, 0.0, 0.1)]
    r = combine(parts)
    # M = 1.54; c = (0, 0.1 * 0.1 / 1.54) = (0, 0.0064935)
    assert r.mass_kg == pytest.approx(1.54)
    assert r.com_m[1] == pytest.approx(0.01 / 1.54)
    # about the origin: 2 (1.2e-3 + 0.72 * 0.16) + 0.003 + 0.1 * 0.01 = 0.2328 + 0.004 = 0.2368
    r0 = combine(parts, (0.0, 0.0))
    assert r0.izz_kgm2 == pytest.approx(2 * (1.2e-3 + 0.72 * 0.16) + 0.003 + 0.001)
    # about the centre: Izz_O - M |c|^2
    assert r.izz_kgm2 == pytest.approx(0.2368 - 1.54 * (0.01 / 1.54) ** 2)
    assert r0.izz_com_kgm2 == pytest.approx(r.izz_kgm2)


def test_uncertainty_matches_monte_carlo():
    parts = [Part("A", 0.72, 1.2e-3, -0.4, 0.05, 1.4e-3, 3e-5, 2e-3),
             Part("B", 0.80, 1.3e-3, 0.35, 0.0, 1.4e-3, 3e-5, 2e-3),
             Part("load", 0.3, 3e-4, 0.02, -0.03, 5e-3, 1e-5, 1e-3)]
    r = combine(parts)
    rng = np.random.default_rng(2)
    n = 40_000
    m = np.array([p.mass_kg for p in parts]) + rng.normal(0, 1, (n, 3)) * [p.mass_sigma_kg for p in parts]
    I = np.array([p.izz_kgm2 for p in parts]) + rng.normal(0, 1, (n, 3)) * [p.izz_sigma_kgm2 for p in parts]
    xy = np.array([[p.x_m, p.y_m] for p in parts]) + rng.normal(0, 1, (n, 3, 2)) * \
        np.array([p.position_sigma_m for p in parts])[:, None]
    c = (m[..., None] * xy).sum(1) / m.sum(1)[:, None]
    izz_c = (I + m * ((xy - c[:, None]) ** 2).sum(2)).sum(1)
    assert r.izz_com_sigma_kgm2 == pytest.approx(izz_c.std(), rel=0.05)
    assert r.mass_sigma_kg == pytest.approx(m.sum(1).std(), rel=0.05)


def test_example_truss_file_matches_a_direct_sum():
    parts, about = load_parts(EXAMPLE)
    assert about == "com" and len(parts) == 8
    r = combine(parts, about)
    M = sum(p.mass_kg for p in parts)
    cx = sum(p.mass_kg * p.x_m for p in parts) / M
    cy = sum(p.mass_kg * p.y_m for p in parts) / M
    direct = sum(p.izz_kgm2 + p.mass_kg * ((p.x_m - cx) ** 2 + (p.y_m - cy) ** 2) for p in parts)
    assert r.izz_kgm2 == pytest.approx(direct)
    rod = next(p for p in parts if p.name.startswith("wooden stick, upper"))
    assert rod.izz_kgm2 == pytest.approx(0.060 * 0.64**2 / 12)
    box = next(p for p in parts if p.name == "central load")
    assert box.izz_kgm2 == pytest.approx(0.3 * 2 * 0.08**2 / 12)


@pytest.mark.parametrize("body,msg", [
    ("[[part]]\nmass_kg = -1\nizz_kgm2 = 0\nposition_m = [0, 0]\n", "positive"),
    ("[[part]]\nmass_kg = 1\nposition_m = [0, 0]\n", "izz_kgm2 or shape"),
    ("[[part]]\nmass_kg = 1\nizz_kgm2 = 0.1\nposition_m = [0]\n", r"\[x, y\]"),
    ("[[part]]\nmass_kg = 1\nshape = 'rod'\nlength_m = -2\nposition_m = [0, 0]\n", "positive"),
    ("title = 'no parts'\n", "no \\[\\[part\\]\\]"),
    ("this is = not toml [", "not valid TOML"),
])
def test_bad_parts_refused(tmp_path, body, msg):
    f = tmp_path / "parts.toml"
    f.write_text(body)
    with pytest.raises(UserError, match=msg):
        load_parts(f)


# issue 16: a misspelled key was ignored (its uncertainty taken as 0, printed as +/- 0)

def test_misspelled_key_is_an_error_naming_the_nearest(tmp_path):
    f = tmp_path / "parts.toml"
    f.write_text('[[part]]\nname = "A"\nmass_kg = 0.72\nizz_kgm2 = 1.2e-3\nposition_m = [0, 0]\n'
                 'mass_sigma = 0.001\n')
    with pytest.raises(UserError, match=r"part 1 \(A\): unknown key 'mass_sigma' "
                                        r"\(did you mean 'mass_sigma_kg'\?\)"):
        load_parts(f)


def test_misspelled_top_level_key(tmp_path):
    f = tmp_path / "parts.toml"
    f.write_text('abut = "com"\n[[part]]\nmass_kg = 1\nizz_kgm2 = 0.1\nposition_m = [0, 0]\n')
    with pytest.raises(UserError, match=r"unknown key 'abut' \(did you mean 'about'\?\)"):
        load_parts(f)


def test_a_bom_is_accepted(tmp_path):
    f = tmp_path / "parts.toml"
    f.write_bytes(b"\xef\xbb\xbf" + EXAMPLE.read_bytes())
    assert load_parts(f) == load_parts(EXAMPLE)
