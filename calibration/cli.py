"""Sub-commands of the `calibration` package (none yet: see the open issues)."""

from __future__ import annotations


def register(sub) -> None:
    """Add this package's commands to the `tpods` parser."""
