"""How a spreadsheet of any locale writes a CSV: the separator read off the header line (it
holds no decimals), and number cells with a decimal comma where the separator is not a
comma. One rule for every reader of lab logs (the generic import table, swing logs)."""

from __future__ import annotations


def is_number(cell: str) -> bool:
    """True when ``cell`` reads as a float."""
    try:
        float(cell)
    except ValueError:
        return False
    return True


def header_delimiter(head: str) -> str | None:
    """``";"`` or tab when the header line uses it and holds no comma (a decimal-comma
    locale's file), else None (the caller's default)."""
    return next((d for d in (";", "\t") if d in head and "," not in head), None)


def decimal_commas(rows: list[list[str]]) -> list[list[str]]:
    """Cells that read as numbers with the comma as the decimal point, so converted; any
    other cell (a vector ``[1, 0]``, text) left as it is."""
    return [[c.replace(",", ".") if "," in c and is_number(c.replace(",", ".")) else c
             for c in r] for r in rows]
