"""Running the installed ``tpods`` command as a user does."""

from __future__ import annotations

import subprocess


def run(exe: str, *args: str, cwd=None, timeout: float = 600) -> subprocess.CompletedProcess:
    """Run ``exe args...``; text output captured."""
    return subprocess.run([exe, *args], capture_output=True, text=True, timeout=timeout, cwd=cwd)
