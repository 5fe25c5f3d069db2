"""Sub-commands of the `mocap_bridge` package (none yet: see the open issues)."""

from __future__ import annotations


def register(sub) -> None:
    """Add this package's commands to the `tpods` parser."""
