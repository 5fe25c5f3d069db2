"""Regression: the emulated bifilar swing (runs/fixtures/bifilar-swing/) through ``tpods
calibrate bifilar --poses`` (the installed command: pose reader, trace fit, budget) gives
its golden Izz and sigma (rel. 1e-9)."""

import json

from tests.support import golden
from tests.support.cli import run_in_process
from tpods.fixtures import FIXTURES_ROOT, bifilar_cli_args, golden_path

FIXTURE = FIXTURES_ROOT / "bifilar-swing"


def test_calibrate_bifilar_gives_the_golden_izz_and_sigma(tpods_exe):
    r = run_in_process(*bifilar_cli_args(FIXTURE), "--json")
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout)
    golden.check_values({k: res[k] for k in ("izz_kgm2", "izz_sigma_kgm2")}, golden_path(FIXTURE),
                        atol=0.0, rtol=1e-9, what="tpods calibrate bifilar on the swing")
    assert abs(res["izz_kgm2"] - 1.2e-3) < 4 * res["izz_sigma_kgm2"]  # the swing's truth
