"""The families of files are folders: each package says in its docstring what it holds and
who may import it, and only those do (docs/architecture.md, "Layout")."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from tests.architecture.test_import_graph import imports_of

ROOT = Path(__file__).resolve().parents[2]
# package -> the module prefixes allowed to import it from outside it (the tests may too)
FAMILIES = {
    "tpods.demo": ("tpods.cli",),
    "estimator.filters": ("estimator.live", "estimator.montecarlo", "estimator.estimate",
                          "estimator.reports", "tpods", "benchmarks"),
    "estimator.batch.thrust_calibration": ("estimator", "tpods", "benchmarks"),
    "calibration.swing": ("calibration", "estimator", "tpods", "benchmarks"),
    "bench.ohaus": ("bench", "calibration", "estimator", "tpods", "benchmarks"),
    "common.mcap": ("common", "bench", "mocap_bridge", "calibration", "estimator", "tpods",
                    "benchmarks"),
    "mocap_bridge.pcap": ("mocap_bridge", "calibration", "estimator", "tpods", "benchmarks"),
    "estimator.reports.plots": ("estimator.reports", "tpods", "benchmarks"),
}
SOURCES = ("common", "bench", "mocap_bridge", "calibration", "estimator", "tpods", "benchmarks")


def outside_importers(package: str, root: Path = ROOT) -> list[str]:
    """Every import of ``package`` from a module outside it that its allowed list does not
    name, as ``file:line imports module``."""
    allowed = FAMILIES[package]
    bad = []
    for src in SOURCES:
        for f in sorted((root / src).rglob("*.py")):
            mod = ".".join(f.relative_to(root).with_suffix("").parts)
            if mod == package or mod.startswith(package + "."):
                continue
            for line, target in imports_of(f):
                if (target == package or target.startswith(package + ".")) and not any(
                        mod == a or mod.startswith(a + ".") for a in allowed):
                    bad.append(f"{f.relative_to(root)}:{line} imports {target}")
    return bad


@pytest.mark.parametrize("package", sorted(FAMILIES))
def test_a_family_is_a_package_that_says_what_it_holds_and_who_may_import_it(package):
    init = ROOT / package.replace(".", "/") / "__init__.py"
    doc = ast.get_docstring(ast.parse(init.read_text()))
    assert doc, f"{init} has no docstring"
    assert "Who may import it" in doc or "who may import it" in doc.lower()
    # every module of the folder is named in the docstring
    names = {p.stem for p in init.parent.glob("*.py") if p.stem != "__init__"}
    missing = sorted(n for n in names if n not in doc)
    assert missing == [], f"{init}: the docstring does not name {missing}"


@pytest.mark.parametrize("package", sorted(FAMILIES))
def test_only_the_named_importers_import_a_family(package):
    assert outside_importers(package) == []


def test_no_module_of_a_family_is_left_beside_its_folder():
    """A prefix is a folder that was never made: no ``demo_*.py`` beside ``tpods/demo/``."""
    left = []
    for package in FAMILIES:
        folder = ROOT / package.replace(".", "/")
        stem = folder.name
        left += [str(p.relative_to(ROOT)) for p in folder.parent.glob(f"{stem}_*.py")]
        left += [str(p.relative_to(ROOT)) for p in folder.parent.glob(f"{stem}.py")]
    assert left == []


def test_the_importer_check_catches_a_forbidden_import(tmp_path):
    for src in SOURCES:
        (tmp_path / src).mkdir()
    (tmp_path / "tpods" / "demo").mkdir()
    (tmp_path / "tpods" / "demo" / "x.py").write_text("")
    (tmp_path / "tpods" / "player.py").write_text("def f():\n    from tpods.demo import x\n")
    (tmp_path / "tpods" / "cli").mkdir()
    (tmp_path / "tpods" / "cli" / "demo.py").write_text("import tpods.demo.x\n")
    assert outside_importers("tpods.demo", tmp_path) == ["tpods/player.py:2 imports tpods.demo"]
