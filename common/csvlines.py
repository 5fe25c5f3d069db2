"""A small CSV text as numbered rows, for readers whose errors name the file's line: the
test-mass series of ``calibrate pendulum-check`` and the load-cell logs of ``bench import``.

Blank lines and lines starting with ``#`` are skipped; a UTF-8 byte-order mark is read past;
the delimiter is a comma, or a tab when the header has tabs and no comma. A cell is read as
a number by :func:`cell_number`.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

from common.errors import UserError


def read_csv_lines(path: str | Path) -> list[tuple[int, list[str]]]:
    """``(line number, cells)`` of every line that is not blank or a comment, the header
    first; a missing or unreadable (binary, not UTF-8) file is a UserError naming it."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise UserError(f"{p}: file not found") from None
    except IsADirectoryError:
        raise UserError(f"{p}: a folder, not a CSV file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise UserError(f"{p}: unreadable ({exc.__class__.__name__}; a CSV text file?)") from None
    lines = [(i, ln) for i, ln in enumerate(text.splitlines(), 1)
             if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        return []
    head = lines[0][1]
    delim = "\t" if "\t" in head and "," not in head else ","
    cells = csv.reader([ln for _, ln in lines], delimiter=delim)
    return [(i, row) for (i, _), row in zip(lines, cells, strict=True)]


def cell_number(cell: str, where: str, what: str = "a number") -> float:
    """The cell as a finite float; else a UserError ``<where>: '<cell>' is not <what>``."""
    try:
        v = float(cell)
    except ValueError:
        v = math.nan
    if not math.isfinite(v):
        raise UserError(f"{where}: {cell!r} is not {what}")
    return v
