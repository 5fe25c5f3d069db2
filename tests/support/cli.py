"""Running `tpods` as a user does: the installed command (:func:`run`) or in process (:func:`main_rc`)."""

from __future__ import annotations

import subprocess


def run(exe: str, *args: str, cwd=None, timeout: float = 600) -> subprocess.CompletedProcess:
    """Run ``exe args...``; text output captured."""
    return subprocess.run([exe, *args], capture_output=True, text=True, timeout=timeout, cwd=cwd)


def main_rc(argv: list[str], capsys) -> tuple[int, str, list[str]]:
    """``tpods`` in process: (exit code, stdout, the non-blank stderr lines)."""
    from tpods.cli import main

    try:
        rc = main(argv)
    except SystemExit as exc:
        rc = exc.code
    out = capsys.readouterr()
    return rc, out.out, [ln for ln in out.err.splitlines() if ln.strip()]
