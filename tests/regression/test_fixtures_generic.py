"""Regression: every fixture under runs/fixtures/ with a fixture.json (the curated ones and
those a lab adds with ``tpods fixture add``) recomputed by its kind's function
(tpods/fixtures.py) against its ``golden/values.json``. ``--update-goldens`` (``make
golden``) rewrites them and prints what moved."""

from __future__ import annotations

import pytest

from tests.support.fixture_check import check_fixture
from tpods.fixtures import FIXTURES_ROOT, list_fixtures

FIXTURES = list_fixtures(FIXTURES_ROOT)


def test_the_curated_fixtures_are_there():
    assert {"live-run", "bifilar-swing", "structure-run"} <= {f.name for f in FIXTURES}


@pytest.mark.parametrize("fixture", FIXTURES, ids=[f.name for f in FIXTURES])
def test_fixture_matches_its_golden(fixture):
    check_fixture(fixture)


@pytest.mark.parametrize("fixture", FIXTURES, ids=[f.name for f in FIXTURES])
def test_fixture_is_small_and_described(fixture):
    size = sum(p.stat().st_size for p in fixture.rglob("*") if p.is_file())
    assert size < 600_000, f"{fixture}: {size} bytes"
    assert (fixture / "README.md").read_text().startswith(f"# {fixture.name}")
