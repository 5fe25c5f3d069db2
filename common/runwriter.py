"""Writing run folders: the one writer every recorder uses (``runfolder`` reads them).

- :class:`CsvLog`: a CSV file written as it goes: the header at once, one row per
  call in the caller's number formats, flushed per row (or every ``flush_every_s``, or
  only at close), so a killed recorder leaves every row it wrote readable.
- :class:`CommandLog`: ``commands.csv`` (``t,d1..dn``) on a :class:`CsvLog`, with the
  run-folder rule that time strictly increases (a row not after the previous is skipped).
- :func:`write_json_atomic`: a JSON file replaced whole (written beside, fsynced,
  renamed): a reader or a crash sees the old file or the new one, never half of one.
- :func:`json_default` / :func:`dumps_json`: the one JSON policy for metadata.
  numpy scalars and arrays become numbers and lists, anything else that JSON has no
  type for (``Path``, ...) its ``str()``. NaN and infinities are written as ``NaN`` and
  ``Infinity`` (Python's json literals, read back by ``json.loads`` and
  :func:`common.runfolder.read_run`), as the recorders always wrote them.
- :func:`run_header`: the first keys of every ``run.json`` (``kind``, ``software``,
  ``created``) followed by the caller's fields.
- :func:`run_status`: a ``run.json`` that says ``running`` while a block runs, then
  ``complete``, ``aborted`` (Ctrl-C) or ``failed`` (any other exception, with ``error``).
  A status other than ``complete``/``success`` marks a partial run
  (:func:`common.runfolder.partial_status`, docs/run-format.md).

Files are UTF-8 with ``\\n`` line ends on every platform.
"""

from __future__ import annotations

import contextlib
import csv
import datetime as _dt
import json
import math
import os
import re
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path
from typing import IO, Any

import numpy as np

from common import __version__

Format = str | Callable[[Any], str]

# A printf conversion whose output can never hold a comma, a quote or a line end: rows
# made only of these are written with one %-format (the fast path, as np.savetxt does).
_NUMERIC_PRINTF = re.compile(r"%[-+ #0]*\d*(?:\.\d+)?[diouxXeEfFgG]")


def json_default(o: Any) -> Any:
    """The JSON policy for values json has no type for: numpy scalars to Python numbers,
    numpy arrays to lists, anything else (``Path``, ...) to its ``str()``."""
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


def dumps_json(data: Any) -> str:
    """``data`` as the toolkit writes JSON files: indent 2, :func:`json_default`, a final newline."""
    return json.dumps(data, indent=2, default=json_default) + "\n"


def write_json_atomic(path: str | Path, data: Any) -> Path:
    """Replace ``path`` with ``data`` as JSON (:func:`dumps_json`), atomically.

    The text is serialised first, written to ``<name>.tmp`` beside the file, fsynced and
    renamed over ``path``: an interrupted write leaves the previous file intact (and no
    ``.tmp`` behind, unless the process is killed between the write and the rename).
    """
    path = Path(path)
    text = dumps_json(data)
    tmp = path.with_name(path.name + ".tmp")
    try:
        with open(tmp, "w", encoding="utf-8", newline="") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise
    return path


def run_header(kind: str, *, created: float | None = None, **fields: Any) -> dict[str, Any]:
    """The header of a ``run.json``: ``kind``, ``software`` (``tpods <version>``),
    ``created`` (UTC, ISO 8601 to the second; ``created`` is a Unix time, default now),
    then ``fields`` in the order given."""
    when = _dt.datetime.now(_dt.UTC) if created is None else _dt.datetime.fromtimestamp(created, _dt.UTC)
    return {"kind": kind, "software": f"tpods {__version__}",
            "created": when.isoformat(timespec="seconds"), **fields}


@contextlib.contextmanager
def run_status(path: str | Path, kind: str, **fields: Any) -> Iterator[dict[str, Any]]:
    """Write ``path`` (a run.json: :func:`run_header` with ``status = "running"``), run the
    block, then rewrite it with its end: ``complete``, ``aborted`` on KeyboardInterrupt,
    ``failed`` (and ``error``) on any other exception, which propagates. A hard kill leaves
    ``running``. Yields the metadata (keys added to it in the block are written at the end)."""
    path = Path(path)
    meta = run_header(kind, status="running", **fields)
    write_json_atomic(path, meta)
    status, error = "failed", None
    try:
        yield meta
        status = "complete"
    except KeyboardInterrupt:
        status, error = "aborted", "interrupted (Ctrl-C)"
        raise
    except BaseException as exc:
        error = str(exc) or exc.__class__.__name__
        raise
    finally:
        meta.update(status=status, error=error)
        with contextlib.suppress(OSError):
            write_json_atomic(path, meta)


def _formatter(fmt: Format | None) -> Callable[[Any], str]:
    if fmt is None:
        return str
    if isinstance(fmt, str):
        return lambda v: fmt % v
    return fmt


class CsvLog:
    """A CSV file written row by row: header at once, one row per :meth:`write` call.

    Args:
        path: the file (created or truncated).
        columns: the header's column names.
        formats: one per column, or one for every column: a printf conversion
            (``"%.12g"``), a callable returning the cell's text, or None (``str``).
            Cells that hold a comma, a quote or a line end are quoted as CSV quotes them.
        flush_every_s: 0 (default) flushes after every row; ``s > 0`` at most every
            ``s`` seconds (and at close); None only at close. The header is always
            flushed at once.
    """

    def __init__(self, path: str | Path, columns: Sequence[str],
                 formats: Format | Sequence[Format | None] | None = None, *,
                 flush_every_s: float | None = 0.0) -> None:
        self.path = Path(path)
        self.columns = tuple(columns)
        if formats is None or isinstance(formats, str) or callable(formats):
            formats = [formats] * len(self.columns)
        formats = list(formats)
        if len(formats) != len(self.columns):
            raise ValueError(f"{len(formats)} formats for {len(self.columns)} columns")
        self._cells = [_formatter(f) for f in formats]
        fast = all(isinstance(f, str) and _NUMERIC_PRINTF.fullmatch(f) for f in formats)
        self._line = ",".join(formats) + "\n" if fast else None  # type: ignore[arg-type]
        self.flush_every_s = flush_every_s
        self.n_rows = 0
        self.fh: IO[str] = open(self.path, "w", encoding="utf-8", newline="")
        self._csv = csv.writer(self.fh, lineterminator="\n")
        self._csv.writerow(self.columns)
        self.fh.flush()
        self._last_flush = time.monotonic()

    def _write(self, values: Sequence[Any]) -> None:
        if len(values) != len(self.columns):
            raise ValueError(f"{self.path.name}: {len(values)} values for {len(self.columns)} columns")
        if self._line is not None:
            self.fh.write(self._line % tuple(values))
        else:
            self._csv.writerow([cell(v) for cell, v in zip(self._cells, values, strict=True)])
        self.n_rows += 1

    def _flushed(self) -> None:
        every = self.flush_every_s
        if every is None:
            return
        if every <= 0:
            self.fh.flush()
            return
        now = time.monotonic()
        if now - self._last_flush >= every:
            self.fh.flush()
            self._last_flush = now

    def write(self, *values: Any) -> None:
        """Append one row (one value per column), then flush as the policy says."""
        self._write(values)
        self._flushed()

    def write_many(self, rows: Iterable[Sequence[Any]]) -> None:
        """Append many rows (an iterable of sequences, or a 2-D array), flushing once."""
        if isinstance(rows, np.ndarray):
            rows = rows.tolist()
        for values in rows:
            self._write(values)
        self._flushed()

    def flush(self) -> None:
        self.fh.flush()
        self._last_flush = time.monotonic()

    @property
    def closed(self) -> bool:
        return self.fh.closed

    def close(self) -> None:
        """Flush and close (again: nothing)."""
        if not self.fh.closed:
            self.fh.close()

    def __enter__(self) -> CsvLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def command_columns(n_channels: int = 4) -> tuple[str, ...]:
    """``("t", "d1", ..., "dn")``."""
    return ("t", *(f"d{i + 1}" for i in range(n_channels)))


class CommandLog(CsvLog):
    """``commands.csv`` (``t,d1..dn``, run-folder format) appended and flushed per row.

    Times are written with ``t_format`` (``%.9g``), duties with ``%.6g``. A time not
    after the previous row's is skipped (:meth:`add` returns False): the run-folder
    contract wants strictly increasing time.
    """

    def __init__(self, path: str | Path, n_channels: int = 4, *, t_format: str = "%.9g",
                 flush_every_s: float | None = 0.0) -> None:
        super().__init__(path, command_columns(n_channels), [t_format] + ["%.6g"] * n_channels,
                         flush_every_s=flush_every_s)
        self.last_t = -math.inf
        self.last_duty: tuple[float, ...] | None = None

    @property
    def rows(self) -> int:
        """Rows written (the header not counted)."""
        return self.n_rows

    def add(self, t: float, duty_pct: Iterable[float]) -> bool:
        """Append a row; a time not after the previous row is skipped (returns False)."""
        if not t > self.last_t:
            return False
        duty = tuple(float(x) for x in duty_pct)
        self.write(t, *duty)
        self.last_t = t
        self.last_duty = duty
        return True
