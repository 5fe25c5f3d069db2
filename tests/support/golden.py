"""Golden outputs beside recorded fixtures (runs/fixtures/*/golden/), for tests/regression.

A regression test computes its outputs from a fixture and calls :func:`check_frame` /
:func:`check_values`. Without ``--update-goldens`` a difference beyond the stated
tolerance fails with a readable diff (what moved, by how much, the tolerance). With
``pytest --update-goldens`` (or ``make golden``) the goldens are rewritten and what moved
is printed; review the diff with ``git diff runs/fixtures`` before committing.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import pandas as pd

UPDATE = {"on": False}
"""Set by tests/conftest.py from ``--update-goldens``."""


class GoldenMismatch(AssertionError):
    pass


def _fmt(x) -> str:
    return f"{x:.17g}" if isinstance(x, float) else repr(x)


def check_frame(actual: pd.DataFrame, path: str | Path, *, atol: float = 1e-12, rtol: float = 0.0,
                atol_columns: Mapping[str, float] | None = None, what: str = "") -> None:
    """``actual`` against the CSV golden at ``path``: same columns and rows, numbers within
    ``atol + rtol*|golden|`` (``atol_columns`` per column), text equal."""
    path = Path(path)
    label = what or path.name
    if UPDATE["on"] or not path.exists():
        old = pd.read_csv(path) if path.exists() else None
        moved = "created" if old is None else _moved(old, actual, atol_columns or {}, atol, rtol)
        if moved != "unchanged":  # within tolerance: the file stays as it is (no diff noise)
            path.parent.mkdir(parents=True, exist_ok=True)
            actual.to_csv(path, index=False)
        print(f"golden {path}: {moved}")
        return
    golden = pd.read_csv(path)
    problems = []
    if list(golden.columns) != list(actual.columns):
        problems.append(f"columns: golden {list(golden.columns)}, now {list(actual.columns)}")
    if len(golden) != len(actual):
        problems.append(f"rows: golden {len(golden)}, now {len(actual)}")
    if not problems:
        problems = _diffs(golden, actual, atol_columns or {}, atol, rtol)
    if problems:
        raise GoldenMismatch(f"{label} differs from its golden {path}:\n  " + "\n  ".join(problems[:20])
                             + (f"\n  ... {len(problems) - 20} more" if len(problems) > 20 else "")
                             + "\n(if the change is intended: pytest --update-goldens, or make golden)")


def _diffs(golden: pd.DataFrame, actual: pd.DataFrame, per: Mapping[str, float], atol: float,
           rtol: float) -> list[str]:
    out = []
    for col in golden.columns:
        g, a = golden[col], actual[col].reset_index(drop=True)
        tol = per.get(col, atol)
        for i in range(len(g)):
            gv, av = g.iloc[i], a.iloc[i]
            if isinstance(gv, (int, float, np.integer, np.floating)) and isinstance(av, (int, float, np.integer, np.floating)):
                gv, av = float(gv), float(av)
                if math.isnan(gv) and math.isnan(av):
                    continue
                if not abs(av - gv) <= tol + rtol * abs(gv):
                    out.append(f"row {i}, {col}: golden {_fmt(gv)}, now {_fmt(av)} "
                               f"(moved {av - gv:+.3g}, tolerance {tol + rtol * abs(gv):.3g})")
            elif str(gv) != str(av):
                out.append(f"row {i}, {col}: golden {gv!r}, now {av!r}")
    return out


def _moved(old: pd.DataFrame, new: pd.DataFrame, per, atol, rtol) -> str:
    if list(old.columns) != list(new.columns) or len(old) != len(new):
        return f"replaced ({len(old)} rows -> {len(new)} rows)"
    d = _diffs(old, new, per, atol, rtol)
    return "unchanged" if not d else "moved:\n  " + "\n  ".join(d[:20])


def check_values(actual: Mapping[str, Sequence[float] | float], path: str | Path, *,
                 atol: float = 1e-12, rtol: float = 0.0, what: str = "") -> None:
    """Named numbers (or lists of numbers) against the JSON golden at ``path``."""
    path = Path(path)
    label = what or path.name
    actual = {k: (list(map(float, v)) if isinstance(v, (list, tuple, np.ndarray)) else float(v))
              for k, v in actual.items()}
    if UPDATE["on"] or not path.exists():
        old = json.loads(path.read_text()) if path.exists() else None
        d = [] if old is None else _value_diffs(old, actual, atol, rtol)
        msg = "created" if old is None else ("unchanged" if not d else "moved:\n  " + "\n  ".join(d))
        if msg != "unchanged":
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(json.dumps(actual, indent=1, sort_keys=True) + "\n")
        print(f"golden {path}: {msg}")
        return
    golden = json.loads(path.read_text())
    problems = _value_diffs(golden, actual, atol, rtol)
    if problems:
        raise GoldenMismatch(f"{label} differs from its golden {path}:\n  " + "\n  ".join(problems)
                             + "\n(if the change is intended: pytest --update-goldens, or make golden)")


def _value_diffs(golden, actual, atol, rtol) -> list[str]:
    out = []
    for k in sorted(set(golden) | set(actual)):
        if k not in golden or k not in actual:
            out.append(f"{k}: {'missing now' if k not in actual else 'new (not in the golden)'}")
            continue
        g = golden[k] if isinstance(golden[k], list) else [golden[k]]
        a = actual[k] if isinstance(actual[k], list) else [actual[k]]
        if len(g) != len(a):
            out.append(f"{k}: golden has {len(g)} values, now {len(a)}")
            continue
        for i, (gv, av) in enumerate(zip(g, a, strict=True)):
            if not abs(av - gv) <= atol + rtol * abs(gv):
                out.append(f"{k}[{i}]: golden {_fmt(gv)}, now {_fmt(av)} (moved {av - gv:+.3g}, "
                           f"tolerance {atol + rtol * abs(gv):.3g})")
    return out
