"""One rule for every door through which valve commands reach an estimator or a valve: a
run's command columns match its vehicle, and on/off valves are commanded in percent.

- **Columns**: commands.csv holds ``d1..dN`` for the N thrusters of its vehicle (4 for the
  TPODS module without one). A column ``d{k}`` beyond them belongs to another vehicle, or to
  a vehicle file that was not given: it is refused, never dropped in silence.
- **Scale**: an on/off valve (``force_n``) is open at 100 % and closed at 0. A run whose open
  duties on those valves are all at most 1 % is a log of 0/1 states read as percent: every
  force 100 times too small, a mass 100 times too small. It is refused, naming the fix.

Pure functions on a header and an array; callers add the file's name.
"""

from __future__ import annotations

import re
from collections.abc import Sequence

import numpy as np

_DUTY = re.compile(r"^d(\d+)$")

ONOFF_STATE_MAX_PCT = 1.0
"""Open duties of on/off valves all at or below this (percent) are 0/1 states, not percent."""


def extra_command_columns(header: Sequence[str], n_channels: int) -> list[str]:
    """The ``d{k}`` columns of ``header`` beyond ``n_channels`` (in the header's order)."""
    out = []
    for h in header:
        m = _DUTY.match(str(h).strip())
        if m and int(m.group(1)) > n_channels:
            out.append(str(h).strip())
    return out


def columns_problem(header: Sequence[str], n_channels: int, what: str) -> str | None:
    """A one-line refusal for command columns beyond the vehicle's (``what``: the vehicle or
    the module, as the message names it), or None."""
    extra = extra_command_columns(header, n_channels)
    if not extra:
        return None
    return (f"column(s) {', '.join(extra)} beyond the {n_channels} valves of {what}: the "
            "commands of another vehicle? give the run's vehicle file (--vehicle FILE), or "
            "remove the columns")


def onoff_scale_problem(duty: np.ndarray, onoff: Sequence[int]) -> str | None:
    """A one-line refusal when every open duty of the on/off channels ``onoff`` (indices)
    is at most :data:`ONOFF_STATE_MAX_PCT` (0/1 states read as percent), or None."""
    if not len(onoff):
        return None
    d = np.asarray(duty, float)[:, list(onoff)]
    opened = d[d > 0]
    if opened.size == 0 or float(opened.max()) > ONOFF_STATE_MAX_PCT:
        return None
    return (f"every open duty of the on/off valves is at most {ONOFF_STATE_MAX_PCT:g} % "
            f"(largest {float(opened.max()):g}): 0/1 valve states read as percent, which would "
            "make every force 100 times too small; duties are percent, an open on/off valve "
            "100 (tpods import commands --as columns reads 0/1 states)")
