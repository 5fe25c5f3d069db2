"""Read a swing trace from another lab's log: a gyro's yaw rate or any angle-like signal.

:func:`read_swing_csv` reads a delimited text file (comma, tab, semicolon or spaces; an
optional header row) into (t s, value), choosing the columns by ``--columns`` (names or
1-based numbers), converting time (s, ms, us) and rates (rad/s, deg/s, rpm), or making
the time from the row number and a frame rate when the log has none (video tracks).
Rows with an empty cell in a chosen column are skipped (loggers write them while a
sensor settles) and counted; text where a number should be is refused on its line.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from common.csv_locale import decimal_commas, header_delimiter, is_number
from common.errors import UserError

TIME_UNITS_S = {"s": 1.0, "ms": 1e-3, "us": 1e-6}
RATE_UNITS_RAD_S = {"rad/s": 1.0, "deg/s": math.pi / 180.0, "rpm": 2.0 * math.pi / 60.0}
TIME_NAMES = ("t", "time", "t_s", "time_s", "timestamp", "time_ms", "t_ms")
EMPTY = ("", "nan", "NaN", "NA", "-")


def parse_columns(text: str | None, allowed: tuple[str, ...]) -> dict[str, str]:
    """``t=COL,rate=COL`` -> {"t": "COL", "rate": "COL"}; keys must be in ``allowed``."""
    out: dict[str, str] = {}
    for item in (text or "").split(","):
        if not item.strip():
            continue
        key, sep, col = item.partition("=")
        key = key.strip()
        if not sep or not col.strip() or key not in allowed:
            raise UserError(f"--columns {text}: expected {','.join(f'{k}=COL' for k in allowed)} "
                            "(COL a header name or a 1-based column number)")
        out[key] = col.strip()
    return out


def _split(path: Path) -> list[list[str]]:
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise UserError(f"{path}: file not found") from None
    except IsADirectoryError:
        raise UserError(f"{path}: is a folder, not a CSV file") from None
    except UnicodeDecodeError:
        raise UserError(f"{path}: not a text file") from None
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise UserError(f"{path}: empty file")
    # the header (no decimals in it) says the separator first: a spreadsheet of a decimal
    # comma locale writes "t;rate" and "0,01;0,30"
    delim = header_delimiter(lines[0])
    if delim is None:
        sample = lines[0] + "\n" + (lines[1] if len(lines) > 1 else "")
        delim = next((d for d in (",", "\t", ";") if d in sample), None)
    if delim is None:
        return [ln.split() for ln in lines]
    rows = [[c.strip() for c in row] for row in csv.reader(lines, delimiter=delim)]
    return decimal_commas(rows) if delim != "," else rows


def _index(col: str, header: list[str] | None, path: Path) -> int:
    if col.isdigit():
        i = int(col) - 1
        if i < 0:
            raise UserError(f"--columns: column numbers start at 1, got {col}")
        return i
    if header is None:
        raise UserError(f"{path}: no header row, so column {col!r} cannot be found by name "
                        "(give its number, 1-based)")
    names = [h.strip().strip('"') for h in header]
    if col not in names:
        raise UserError(f"{path}: no column {col!r} (the header has {', '.join(names)})")
    return names.index(col)


def read_swing_csv(path: str | Path, value_key: str, columns: str | None = None, *,
                   time_unit: str = "s", value_scale: float = 1.0,
                   sample_rate_hz: float | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """(t in s, value times ``value_scale``, rows skipped for an empty cell) from a log.

    Default columns: time is the header's t/time column, else the first; the value is
    ``value_key``'s column by name, else the first column that is not the time. With
    ``sample_rate_hz`` the time is row / rate and no time column is read.
    """
    path = Path(path)
    if time_unit not in TIME_UNITS_S:
        raise UserError(f"--time-unit {time_unit}: expected one of {', '.join(TIME_UNITS_S)}")
    rows = _split(path)
    header = None if all(is_number(c) or c in EMPTY for c in rows[0]) else rows[0]
    data = rows[1:] if header is not None else rows
    cols = parse_columns(columns, ("t", value_key))
    names = [h.strip().strip('"').lower() for h in header] if header else []
    if sample_rate_hz is not None:
        it = None
    elif "t" in cols:
        it = _index(cols["t"], header, path)
    else:
        it = next((names.index(n) for n in TIME_NAMES if n in names), None)
        if it is None and header is not None and (len(names) < 2 or names[0] == value_key):
            raise UserError(f"{path}: no time column (the header has {', '.join(names)}): give "
                            "one with --columns t=COL, or --sample-rate HZ for a log of samples "
                            "at a steady rate")
        it = 0 if it is None else it
    if value_key in cols:
        iv = _index(cols[value_key], header, path)
    elif value_key in names:
        iv = names.index(value_key)
    else:
        iv = next((i for i in range(max(len(r) for r in rows)) if i != it), 1)
    t, v, skipped = [], [], 0
    first = 2 if header is not None else 1
    for n, row in enumerate(data):
        cells = [row[i] if i < len(row) else "" for i in ((iv,) if it is None else (it, iv))]
        if any(c in EMPTY for c in cells):
            skipped += 1
            continue
        try:
            nums = [float(c) for c in cells]
        except ValueError:
            raise UserError(f"{path}: data row {n + first}: not a number in the chosen columns "
                            f"({', '.join(cells)}); choose them with --columns") from None
        if it is None:
            t.append(n / sample_rate_hz)
            v.append(nums[0] * value_scale)
        else:
            t.append(nums[0] * TIME_UNITS_S[time_unit])
            v.append(nums[1] * value_scale)
    if len(v) < 20:
        raise UserError(f"{path}: {len(v)} usable rows; a swing needs at least 20")
    if it is not None and "t" not in cols and not any(n in names for n in TIME_NAMES) \
            and np.any(np.diff(t) <= 0):
        what = f"column {names[it]!r}" if names else "the first column"
        raise UserError(f"{path}: {what}, taken as the time (no t/time column), does not "
                        "increase: give the time column with --columns t=COL, or --sample-rate "
                        "HZ for a log of samples at a steady rate")
    return np.asarray(t), np.asarray(v), skipped
