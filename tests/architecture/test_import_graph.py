"""The layout in floors: every package imports only from the floors below it.

Floors (README "Layout", docs/architecture.md): ``common`` (ground) < ``bench``,
``mocap_bridge`` (devices and data) < ``calibration`` (reads the balance through bench)
< ``estimator`` < ``tpods`` (the application: CLI, demo, player, plant-in-the-loop).
Inside ``estimator/`` the subpackages have floors of their own: ``plant`` < ``shooting`` < ``batch`` <
``filters`` < ``live``, ``montecarlo``, ``estimate`` < ``reports``. Packages on one floor do not import
each other. Imports inside functions count too.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
FLOORS = {"common": 0, "bench": 1, "mocap_bridge": 1, "calibration": 2, "estimator": 3, "tpods": 4}
ESTIMATOR_FLOORS = {"plant": 0, "shooting": 1, "batch": 2, "filters": 3, "live": 4, "montecarlo": 4, "estimate": 4,
                    "reports": 5}


def imports_of(path: Path) -> list[tuple[int, str]]:
    """(line, imported module) of every absolute import in a file, nested ones included."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.append((node.lineno, node.module))
    return out


def _unit(parts: tuple[str, ...] | list[str], floors: dict[str, int]) -> str | None:
    return parts[0] if parts and parts[0] in floors else None


def violations(root: Path = ROOT) -> list[str]:
    """Every import that goes to the same or a higher floor of another package (or of
    another estimator subpackage)."""
    bad = []
    for pkg, floor in FLOORS.items():
        for f in sorted((root / pkg).rglob("*.py")):
            rel = f.relative_to(root)
            inner = _unit(rel.with_suffix("").parts[1:], ESTIMATOR_FLOORS) if pkg == "estimator" else None
            for line, mod in imports_of(f):
                parts = mod.split(".")
                top = parts[0]
                if top in FLOORS and top != pkg and FLOORS[top] >= floor:
                    bad.append(f"{rel}:{line} imports {mod} (floor {FLOORS[top]} from floor {floor})")
                elif top == pkg == "estimator" and inner is not None:
                    target = _unit(parts[1:], ESTIMATOR_FLOORS)
                    if target and target != inner and ESTIMATOR_FLOORS[target] >= ESTIMATOR_FLOORS[inner]:
                        bad.append(f"{rel}:{line} imports {mod} (estimator/{target} is not below "
                                   f"estimator/{inner})")
    return bad


def test_no_upward_sideways_or_circular_import():
    assert violations() == []


def test_the_checker_catches_upward_sideways_and_inner_imports(tmp_path):
    for pkg in FLOORS:
        (tmp_path / pkg).mkdir()
    (tmp_path / "common" / "x.py").write_text("def f():\n    from estimator.plant import model\n")
    (tmp_path / "bench" / "y.py").write_text("import mocap_bridge.pose\n")
    (tmp_path / "estimator" / "plant").mkdir()
    (tmp_path / "estimator" / "plant" / "z.py").write_text("from estimator.filters.ekf import run_ekf\n")
    (tmp_path / "tpods" / "ok.py").write_text("from estimator.plant.model import PlantParams\n")
    assert violations(tmp_path) == [
        "common/x.py:2 imports estimator.plant (floor 3 from floor 0)",
        "bench/y.py:1 imports mocap_bridge.pose (floor 1 from floor 1)",
        "estimator/plant/z.py:1 imports estimator.filters.ekf (estimator/filters is not below "
        "estimator/plant)",
    ]


@pytest.mark.parametrize("pkg", sorted(FLOORS))
def test_every_floor_exists(pkg):
    assert (ROOT / pkg / "__init__.py").exists()


@pytest.mark.parametrize("sub", sorted(ESTIMATOR_FLOORS))
def test_every_estimator_floor_exists(sub):
    assert (ROOT / "estimator" / sub / "__init__.py").exists() or (ROOT / "estimator" / f"{sub}.py").exists()


def module_files(root: Path = ROOT) -> dict[str, Path]:
    """Dotted module name -> file, for every module of the floors' packages."""
    out = {}
    for pkg in FLOORS:
        for f in sorted((root / pkg).rglob("*.py")):
            parts = f.relative_to(root).with_suffix("").parts
            out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = f
    return out


def file_imports(path: Path, module: str, modules: dict[str, Path]) -> set[str]:
    """The project modules a file imports (nested and relative imports too): ``from a.b import c``
    names the module ``a.b.c`` when that is a file, else ``a.b``."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    out = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[:len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, *([base] if base else [])])
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base
                       for a in node.names]
        else:
            continue
        out.update(t for t in targets if t in modules and t != module)
    return out


def import_cycles(root: Path = ROOT) -> list[list[str]]:
    """Every set of modules that import each other, directly or round a loop (Tarjan's
    strongly connected components of the file-level import graph, imports inside functions
    included), each sorted."""
    modules = module_files(root)
    graph = {m: sorted(file_imports(f, m, modules)) for m, f in modules.items()}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            scc = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                scc.append(w)
                if w == v:
                    break
            if len(scc) > 1:
                cycles.append(sorted(scc))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(cycles)


def test_no_file_imports_a_file_that_imports_it_back():
    assert import_cycles() == []


def test_the_cycle_checker_catches_pairs_loops_and_relative_imports(tmp_path):
    for pkg in FLOORS:
        (tmp_path / pkg).mkdir()
        (tmp_path / pkg / "__init__.py").write_text("")
    (tmp_path / "common" / "a.py").write_text("def f():\n    from common import b\n")
    (tmp_path / "common" / "b.py").write_text("import common.a\n")
    (tmp_path / "bench" / "x.py").write_text("from .y import g\n")
    (tmp_path / "bench" / "y.py").write_text("from bench.z import h\n")
    (tmp_path / "bench" / "z.py").write_text("from bench.x import k\n")
    (tmp_path / "tpods" / "ok.py").write_text("from common.a import f\nimport bench.x\n")
    (tmp_path / "tpods" / "sub").mkdir()
    (tmp_path / "tpods" / "sub" / "__init__.py").write_text("from .inner import v\n")
    (tmp_path / "tpods" / "sub" / "inner.py").write_text("from tpods.ok import f\n")
    assert import_cycles(tmp_path) == [["bench.x", "bench.y", "bench.z"], ["common.a", "common.b"]]
