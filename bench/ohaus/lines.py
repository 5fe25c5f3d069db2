"""OHAUS balance lines: what one printed line is (pure, no I/O).

A weight line is a right-justified signed number, a space, the unit, then ``?`` when
unstable (``      12.34 g ?``); Navigator, Explorer, Ranger and Defender lines may carry
a legend after it (gross, net, tare, preset tare, total), a centre-of-zero mark or a time
stamp, and may leave the unit field blank. :func:`parse_line` classifies a line (load
reading, not a load reading, refused, with the reason), :func:`parse_weight_line` returns
the :class:`Reading` or None. Sources: docs/valve-protocol.md ("OHAUS balance lines").
The driver that reads these lines from a balance is :mod:`bench.ohaus.driver`.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

TO_GRAMS = {"g": 1.0, "kg": 1000.0, "mg": 1e-3, "ct": 0.2, "oz": 28.349523125,
            "lb": 453.59237, "ozt": 31.1034768, "dwt": 1.55517384, "gn": 0.06479891,
            "tl": 37.429, "mom": 3.75}
"""Grams per unit for the units a Scout prints (``tl``: Hong Kong tael)."""

KNOWN_UNITS = {u.lower(): u for u in TO_GRAMS} | {"n": "N", "pcs": "PCS", "%": "%"}
"""Unit field (lower-cased) -> the unit symbol it names."""

GROSS, NET = "gross", "net"
_LEGENDS = {"g": GROSS, "b/g": GROSS, "gross": GROSS, "gs": GROSS,
            "n": NET, "net": NET, "nt": NET,
            "t": "tare", "tare": "tare", "pt": "preset tare",
            "total": "total", "tot": "total", "accum": "total"}
"""Legends (lower-cased) -> what the number is. ``G``, ``B/G``, ``GROSS`` gross; ``N``,
``NET``, ``Net`` net (``GS``/``NT``: other makers' spellings, kept); ``T``/``Tare`` the
stored tare value, ``PT`` a preset tare, ``TOTAL`` an accumulated total: those three are
not the load on the pan. Sources: docs/valve-protocol.md, "OHAUS balance lines"."""
_NOT_LOAD = ("tare", "preset tare", "total")
_MARKS = {"c", "st", "a", "o", "u", "accept", "under", "over"}
"""Accepted marks that change nothing: ``C`` centre of zero, ``ST`` stable (other makers),
check-weighing status ``A``/``O``/``U`` (older Navigator) and ``Accept``/``Under``/``Over``
(Defender 5000)."""
_UNSTABLE_FLAGS = {"?", "us"}
_TIME = re.compile(r"^\d{1,2}:\d{2}:\d{2}$")
_WEIGHT = re.compile(
    r"^\s*(?P<pre>\?\s*)?(?P<sign>[-+])?\s*(?P<num>\d+(?:[.,]\d*)?|[.,]\d+)"
    r"(?P<rest>(?:\s*[A-Za-z%?]|\s).*)?$")
_LABEL_FIRST = re.compile(r"^\s*(?P<label>[A-Za-z/]+):?\s+(?P<body>[-+?\d.,].*)$")


@dataclass(frozen=True)
class Reading:
    """One balance reading: ``value`` in ``unit``, ``stable`` flag, host monotonic time ``t``,
    ``legend`` ``"gross"``/``"net"`` when the balance printed one (None: no legend)."""

    value: float
    unit: str
    stable: bool
    t: float = math.nan
    legend: str | None = None

    @property
    def grams(self) -> float | None:
        """The reading in grams (gram-force on a thrust bench), None for a non-mass unit."""
        f = TO_GRAMS.get(self.unit)
        return None if f is None else self.value * f


@dataclass(frozen=True)
class LineResult:
    """What one line is: ``kind`` ``"reading"`` (``reading`` set), ``"not_load"`` (a tare,
    preset-tare or total line: well formed, but not the load on the pan) or ``"refused"``
    (garbage, partial or ambiguous); ``reason`` says why for the last two."""

    kind: str
    reading: Reading | None = None
    reason: str = ""
    legend: str | None = None


def _refused(reason: str) -> LineResult:
    return LineResult("refused", reason=reason)


def _parse_body(text: str, t: float, unit: str | None) -> LineResult:
    m = _WEIGHT.match(text)
    if m is None:
        return _refused("no number where the weight field should be")
    toks = (m["rest"] or "").replace("?", " ? ").split()
    unit_sym = None
    n_ambiguous = False
    if toks:
        first = toks[0]
        sym = KNOWN_UNITS.get(first.lower())
        legend_too = first.lower() in _LEGENDS
        if sym is not None and not legend_too:
            unit_sym = sym
        elif sym is not None and first.lower() == "n":
            # newton, or the net legend with print unit off; 'N ... N': unit then legend
            if unit == "N" or any(_LEGENDS.get(x.lower()) == NET for x in toks[1:]):
                unit_sym = "N"
            else:
                n_ambiguous = True
        elif sym is not None and first == sym:
            unit_sym = sym  # 'g': grams are printed lower case; 'G' is the gross legend
        if unit_sym is not None:
            toks = toks[1:]
    stable = m["pre"] is None
    kinds: list[str] = []
    for tok in toks:
        low = tok.lower()
        if low in _UNSTABLE_FLAGS:
            stable = False
        elif low in _LEGENDS:
            kinds.append(_LEGENDS[low])
        elif low in _MARKS or _TIME.match(tok):
            pass
        else:
            what = "unit" if unit_sym is None and tok is toks[0] else "field"
            return _refused(f"unknown {what} {tok!r} after the number")
    value = float(m["num"].replace(",", "."))
    if m["sign"] == "-":
        value = -value
    if not math.isfinite(value):
        return _refused("the number is not finite")
    not_load = [k for k in _NOT_LOAD if k in kinds]
    if not_load:
        return LineResult("not_load", reason=f"a {not_load[0]} line, not the load on the pan",
                          legend=not_load[0])
    if len(set(kinds)) > 1:
        return _refused("both a gross and a net legend: ambiguous")
    legend = kinds[0] if kinds else None
    if unit_sym is None:
        if not toks:
            return _refused("a number with neither unit nor legend (a partial line, or print "
                            "unit off with no legend): ambiguous")
        if n_ambiguous and unit is None:
            return _refused("'N' after the number is either the unit newton or the net legend "
                            "with print unit off, and no unit was verified on the balance (PU): "
                            "ambiguous")
        if unit is None:
            return _refused("no unit field (print unit off?) and no unit verified on the "
                            "balance (PU)")
        unit_sym = unit
    return LineResult("reading", Reading(value, unit_sym, stable, t, legend), legend=legend)


def parse_line(line: bytes | str, t: float = math.nan, unit: str | None = None) -> LineResult:
    """Classify one line from an OHAUS balance (see :func:`parse_weight_line`).

    ``unit``: the unit verified on the balance (``PU``), used only for a line whose unit
    field is empty (print unit off) and to read a lone ``N`` (newton or net legend)."""
    if isinstance(line, bytes):
        try:
            line = line.decode("ascii")
        except UnicodeDecodeError:
            return _refused("bytes that are not ASCII")
    line = line.strip("\r\n\x00")
    if not line.strip():
        return _refused("an empty line")
    if not line.isprintable():
        return _refused("control characters in the line")
    m = _LABEL_FIRST.match(line)
    if m is None or m["label"].lower() not in _LEGENDS:
        return _parse_body(line, t, unit)
    # legend first (Ranger print-key block 'G ... 12.34 kg', 7000-series label field)
    label = _LEGENDS[m["label"].lower()]
    res = _parse_body(m["body"], t, unit)
    if res.kind == "refused":
        return res
    if label in _NOT_LOAD:
        return LineResult("not_load", reason=f"a {label} line, not the load on the pan", legend=label)
    if res.kind == "not_load":
        return res
    r = res.reading
    assert r is not None
    if r.legend not in (None, label):
        return _refused(f"legend {m['label']!r} before the number and {r.legend!r} after it: ambiguous")
    return LineResult("reading", Reading(r.value, r.unit, r.stable, r.t, label), legend=label)


def parse_weight_line(line: bytes | str, t: float = math.nan, unit: str | None = None) -> Reading | None:
    """Parse one weight line of an OHAUS balance; None if it is not a load reading.

    Reads the Scout, Scout Pro, Navigator, Explorer, Adventurer, Ranger and Defender
    layouts: a right-justified number (sign possibly apart from the digits, decimal
    comma accepted, ``?`` before it = unstable), the unit (possibly glued to the number),
    ``?`` when unstable, then legends: ``G``/``B/G``/``GROSS`` and ``N``/``NET`` keep the
    value and set ``Reading.legend``; ``C`` (centre of zero), check-weighing marks and an
    interval-print time stamp ``hh:mm:ss`` are accepted. None for a tare (``T``), preset
    tare (``PT``) or total (``TOTAL``) line, a line whose unit field is empty while no
    ``unit`` was verified (a lone ``N`` is the net legend or the unit newton: read by the
    verified unit, never guessed), a bare number, unknown units or fields, stray characters
    and non-finite numbers. :func:`parse_line` says which and why.
    """
    return parse_line(line, t, unit).reading

