"""Console output shared by the estimate commands (``estimate batch`` with every method,
``estimate crlb``, ``estimate montecarlo``, ``estimate live``, ``design``): one JSON object
on stdout, a result JSON file, a warning line, and :func:`report`, which writes, warns and
prints a use case's report. The text of the results is
:mod:`estimator.reports.estimate_text`'s.
"""

from __future__ import annotations

import json
import sys
from typing import Any


def print_json(obj: dict[str, Any]) -> None:
    """``obj`` as exactly one JSON object on stdout (numpy values as numbers)."""
    from common.runwriter import json_default

    sys.stdout.write(json.dumps(obj, default=json_default) + "\n")


def write_json(path, obj: dict[str, Any]) -> None:
    """``obj`` as an indented JSON file at ``path`` (other values as their ``str``)."""
    path.write_text(json.dumps(obj, indent=2, default=str) + "\n")


def warn(text: str) -> None:
    """One ``tpods: warning:`` line on stderr."""
    print(f"tpods: warning: {text}", file=sys.stderr)


def report(out_folder, rep, as_json: bool, rc: int = 0) -> int:
    """Write ``rep``'s files (``rep.write(main, folder)`` into ``out_folder``, a
    :func:`common.outputs.result_output` or None), say its ``late_warnings``, and print it:
    ``rep.json_text()``, or its ``text_warnings`` (stderr), ``lines()`` and what was written
    (``folder_files``: None for no such line). Returns ``rc``."""
    if out_folder is not None:
        with out_folder.writing_main() as (main, d):  # d: None for --out FILE.json
            rep.write(main, d)
    for w in getattr(rep, "late_warnings", ()):
        warn(w)
    if as_json:
        sys.stdout.write(rep.json_text() + "\n")
        return rc
    for w in getattr(rep, "text_warnings", ()):
        warn(w)
    for line in rep.lines():
        print(line)
    if out_folder is not None and rep.folder_files is not None:
        print(f"  wrote {out_folder.main}" + (rep.folder_files if out_folder.is_folder else ""))
    return rc
