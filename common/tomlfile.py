"""Reading the toolkit's TOML input files (thrust tables, structure.toml, vehicle.toml,
PARTS.toml): the file itself (:func:`read_toml`; its bytes, :func:`read_bytes`, serve
the other text inputs too), the numbers in it (:func:`toml_number`,
:func:`toml_pair`) and its keys (:func:`check_keys`, with a did-you-mean), each problem a
:class:`~common.errors.UserError` of one line that names the file.
"""

from __future__ import annotations

import difflib
import math
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from common.errors import UserError


def read_bytes(path: str | Path, what: str, it: str | None = None) -> bytes:
    """The bytes of the input file ``path``; a missing or unreadable one is a UserError
    ``<path>: <what> not found`` or ``<path>: cannot read <it> (<why>)`` (``it``: "the
    <what>" unless given)."""
    try:
        return Path(path).read_bytes()
    except FileNotFoundError:
        raise UserError(f"{path}: {what} not found") from None
    except OSError as exc:
        why = exc.strerror or exc
        raise UserError(f"{path}: cannot read {it or 'the ' + what} ({why})") from None


def read_toml(path: str | Path, what: str) -> dict[str, Any]:
    """The TOML document in ``path`` (``what``: "thrust table", "structure file", ... in
    the messages). A UTF-8 byte order mark (Windows Notepad, PowerShell) is skipped; CRLF
    line ends are TOML; UTF-16 or other non-UTF-8 text is refused naming the line."""
    path = Path(path)
    raw = read_bytes(path, what)
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
        raise UserError(f"{path}: UTF-16 text; TOML must be UTF-8 (save it as UTF-8)")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw[:exc.start].count(b"\n") + 1
        raise UserError(f"{path}: line {line}: byte 0x{raw[exc.start]:02x} is not UTF-8 "
                        f"(TOML must be UTF-8; save it as UTF-8)") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise UserError(f"{path}: not valid TOML ({exc})") from None


def toml_number(x: Any, what: str, *, positive: bool = False, nonneg: bool = False) -> float:
    """``x`` as a float: a finite number (not a boolean), positive or >= 0 if asked;
    else a UserError naming ``what`` (the file and key)."""
    if isinstance(x, bool) or not isinstance(x, int | float) or not math.isfinite(x):
        raise UserError(f"{what} must be a finite number, got {x!r}")
    if positive and x <= 0:
        raise UserError(f"{what} must be positive, got {x!r}")
    if nonneg and x < 0:
        raise UserError(f"{what} must be >= 0, got {x!r}")
    return float(x)


def nearest_key(key: str, valid: tuple[str, ...]) -> str:
    """`` (did you mean 'x'?)`` for the valid key closest to ``key``, or ``""``."""
    near = difflib.get_close_matches(key, valid, n=1, cutoff=0.5)
    return f" (did you mean {near[0]!r}?)" if near else ""


def check_keys(data: Mapping[str, Any], valid: tuple[str, ...], where: str) -> None:
    """UserError ``<where>unknown key 'k' (did you mean ...?); valid: ...`` for the first
    key of ``data`` not in ``valid``."""
    for key in data:
        if key not in valid:
            raise UserError(f"{where}unknown key {key!r}{nearest_key(key, valid)}; valid: "
                            f"{', '.join(valid)}")


def toml_pair(x: Any, what: str) -> tuple[float, float]:
    """``x`` as two finite numbers ``[x, y]``; else a UserError naming ``what``."""
    if not isinstance(x, list | tuple) or len(x) != 2:
        raise UserError(f"{what} must be two numbers [x, y], got {x!r}")
    return toml_number(x[0], what), toml_number(x[1], what)
