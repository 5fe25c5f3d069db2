"""The numeric CSV reader of run folders (commands, thrusts, poses, truth): exactly-named
columns, refused by file line. Python's ``csv`` module, not pandas: every ``tpods`` command
that reads a run paid pandas' import (about 0.3 s of CPU) for this one reader.

What it reads (spreadsheets and editors write these): a UTF-8 byte order mark, CRLF or CR
line ends, blank lines and lines of empty cells (skipped), spaces around values, quoted
headers and cells, columns in any order, extra columns (ignored, whatever their encoding),
values after the header's columns (ignored when the first data row has them too) and a
trailing comma. A row longer than the first data row is refused (an unquoted decimal comma).
"""

from __future__ import annotations

import csv
import math
import re
from pathlib import Path

import numpy as np

from common.errors import UserError

_UTF16_BOMS = (b"\xff\xfe", b"\xfe\xff")
_LINE_END = re.compile(r"\r\n|\r|\n")


def _number(cell: str) -> float:
    """The cell's value; NaN for what is not a plain decimal number (``1_000`` included)."""
    s = cell.strip()
    if not s or "_" in s:
        return math.nan
    try:
        return float(s)
    except ValueError:
        return math.nan


def read_table(path: Path, columns: tuple[str, ...]) -> np.ndarray:
    """Read a numeric CSV with exactly-named columns; refuse bad content by row (see
    :func:`read_table_lines`)."""
    return read_table_lines(path, columns)[0]


def read_table_lines(path: Path, columns: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """The values (rows, len(columns)) of a numeric CSV with exactly-named columns, and
    each row's file line (header = line 1 unless blank lines precede it). UserError naming
    the file and the line: missing columns, a cell that is not a finite number, a time
    (first column) that does not increase."""
    if not path.is_file():
        raise UserError(f"{path}: file not found")
    data = path.read_bytes()
    if data.startswith(_UTF16_BOMS):
        raise UserError(f"{path}: UTF-16 text (Excel's 'Unicode Text'); save it as 'CSV UTF-8' or plain CSV")
    # Bytes that are not UTF-8 (Excel's plain 'CSV' is in the Windows code page) can only
    # matter in extra columns: a replaced character in a required cell is refused below.
    text = data.decode("utf-8-sig", errors="replace")
    lines = _LINE_END.split(text)
    blank = [not ln.replace(",", "").replace('"', "").strip() for ln in lines]
    if all(blank):
        raise UserError(f"{path}: file is empty")
    header_idx = blank.index(False)
    reader = csv.reader(lines[header_idx:], skipinitialspace=True, strict=True)
    try:
        header = [c.strip() for c in next(reader)]
        missing = [c for c in columns if c not in header]
        if missing:
            hint = ""
            head = lines[header_idx]
            for sep, name in ((";", "semicolons"), ("\t", "tabs")):
                if sep in head and "," not in head:
                    hint = f"; the header is separated by {name}, the format uses commas"
            raise UserError(f"{path}: missing column(s) {', '.join(missing)} "
                            f"(header must hold {','.join(columns)}{hint})")
        idx = [header.index(c) for c in columns]
        width = len(header)
        expected: int | None = None
        rows: list[list[float]] = []
        raws: list[list[str]] = []
        line_no: list[int] = []
        for rec in reader:
            if expected is None:  # the first data row sets the row length (pandas' rule)
                expected = max(width, len(rec))
            elif len(rec) > expected and any(c.strip() for c in rec[expected:]):
                # an unquoted decimal comma makes a row a field longer than the others
                raise UserError(f"{path}: not a readable CSV (Expected {expected} fields in "
                                f"line {header_idx + reader.line_num}, saw {len(rec)})")
            cells = rec[:width]
            if not any(c.strip() for c in cells):
                continue  # a blank line or a line of empty cells
            raw = [cells[i] if i < len(cells) else "" for i in idx]
            rows.append([_number(c) for c in raw])
            raws.append(raw)
            line_no.append(header_idx + reader.line_num)
    except csv.Error as exc:
        raise UserError(f"{path}: not a readable CSV (line {header_idx + reader.line_num}: "
                        f"{exc})") from None
    if not rows:
        raise UserError(f"{path}: no data rows")
    values = np.array(rows, dtype=float).reshape(len(rows), len(columns))
    lines_arr = np.array(line_no, dtype=int)
    bad = ~np.isfinite(values)
    if bad.any():
        row, col = np.argwhere(bad)[0]
        cell = raws[row][col].strip()
        shown = "empty cell" if not cell else repr(cell)
        raise UserError(f"{path}: line {lines_arr[row]}: column {columns[col]} is not a finite "
                        f"number ({shown})")
    t = values[:, 0]
    nonincr = np.nonzero(np.diff(t) <= 0)[0]
    if nonincr.size:
        i = nonincr[0] + 1
        raise UserError(f"{path}: line {lines_arr[i]}: time {t[i]:g} does not increase "
                        f"(previous {t[i - 1]:g})")
    return values, lines_arr


def header_of(path: Path) -> list[str]:
    """The column names of a CSV's first non-blank line (stripped; [] for an empty file)."""
    text = path.read_bytes().decode("utf-8-sig", errors="replace")
    for line in _LINE_END.split(text):
        if line.replace(",", "").replace('"', "").strip():
            return [c.strip() for c in next(csv.reader([line], skipinitialspace=True))]
    return []
