"""Shared test fixtures."""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

import pytest

os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture(scope="session")
def tpods_exe() -> str:
    """The installed ``tpods`` console script (the one a user runs)."""
    exe = Path(sys.executable).with_name("tpods")
    if exe.exists():
        return str(exe)
    found = shutil.which("tpods")
    if not found:
        pytest.fail("the tpods console script is not installed; run `make setup`")
    return found
