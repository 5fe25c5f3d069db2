"""The generic regression check of a recorded fixture (runs/fixtures/NAME/ with fixture.json):
recompute its golden values with :func:`tpods.fixtures.compute_goldens` (what ``tpods
fixture add`` wrote them with) and compare with ``golden/values.json`` through
tests/support/golden.py, at the tolerance of its kind (:data:`tpods.fixtures.TOLERANCES`)."""

from __future__ import annotations

from pathlib import Path

from tests.support import golden
from tpods.fixtures import TOLERANCES, compute_goldens, golden_path, read_fixture_json


def check_fixture(folder: str | Path) -> None:
    folder = Path(folder)
    kind = read_fixture_json(folder)["kind"]
    atol, rtol = TOLERANCES[kind]
    golden.check_values(compute_goldens(folder, kind), golden_path(folder), atol=atol, rtol=rtol,
                        what=f"fixture {folder.name} ({kind})")
