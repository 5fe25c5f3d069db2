"""Regression: the two-module structure run (runs/fixtures/structure-run/) through ``tpods
estimate batch --json`` (the installed command: run folder reader, structure, batch LS)
gives its golden mass, Izz about the centre of mass, centre of mass and their sigmas (rel.
1e-9: the fit is deterministic; the margin covers another BLAS)."""

import json

from tests.support import golden
from tests.support.cli import run_in_process
from tpods.fixtures import FIXTURES_ROOT, golden_path

FIXTURE = FIXTURES_ROOT / "structure-run"
KEYS = ("mass_kg", "mass_sigma_kg", "izz_kgm2", "izz_sigma_kgm2", "com_x_m", "com_x_sigma_m",
        "com_y_m", "com_y_sigma_m")


def test_estimate_batch_gives_the_golden_mass_izz_and_centre_of_mass(tpods_exe):
    r = run_in_process("estimate", "batch", str(FIXTURE), "--json")
    assert r.returncode == 0, r.stderr
    est = json.loads(r.stdout)
    assert est["structure"] == "truss" and est["converged"]
    golden.check_values({k: est[k] for k in KEYS}, golden_path(FIXTURE), atol=0.0, rtol=1e-9,
                        what="tpods estimate batch on the structure run")
    # and the estimate is right: within 4 sigma of the truth (run.json; the fixture's
    # structure.toml has no [body]: everything is estimated)
    assert est["known_from_structure"] == {} and est["estimated"] == ["mass", "izz", "cx", "cy"]
    assert abs(est["mass_kg"] - 1.6) < 4 * est["mass_sigma_kg"]
    assert abs(est["com_x_m"] - 0.03) < 4 * est["com_x_sigma_m"]
