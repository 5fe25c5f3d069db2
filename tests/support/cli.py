"""Running `tpods` as a user does: the installed command (:func:`run`), the same in the test
process with the same result object (:func:`run_in_process`), or in process with pytest's
capture (:func:`main_rc`)."""

from __future__ import annotations

import contextlib
import io
import subprocess
import sys
import warnings


def run(exe: str, *args: str, cwd=None, timeout: float = 600) -> subprocess.CompletedProcess:
    """Run ``exe args...``; text output captured."""
    return subprocess.run([exe, *args], capture_output=True, text=True, timeout=timeout, cwd=cwd)


def run_in_process(*args: str, cwd=None) -> subprocess.CompletedProcess:
    """``tpods args...`` through :func:`tpods.cli.main` in this process, as :func:`run` gives
    it: exit status (argparse's ``SystemExit`` included), stdout and stderr, warnings written
    to stderr as a fresh interpreter shows them (each place once); an exception other than
    the CLI's own handling propagates (a subprocess would have printed a traceback). For tests
    of what a command computes and prints, where a process of its own (about 0.3 s CPU to
    start) adds nothing; the console script itself is tested by tests/tpods/cli/test_main.py."""
    from tpods.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.ExitStack() as stack:
        if cwd is not None:
            stack.enter_context(contextlib.chdir(cwd))
        caught = stack.enter_context(warnings.catch_warnings(record=True))
        warnings.simplefilter("default")  # a fresh interpreter's filters
        for category in (DeprecationWarning, PendingDeprecationWarning, ImportWarning,
                         ResourceWarning):
            warnings.filterwarnings("ignore", category=category)
        stack.enter_context(contextlib.redirect_stdout(out))
        stack.enter_context(contextlib.redirect_stderr(err))
        try:
            rc = main(list(args))
        except SystemExit as exc:
            rc = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
            if isinstance(exc.code, str):
                print(exc.code, file=err)
        finally:
            if "matplotlib.pyplot" in sys.modules:  # what the process would have ended with
                sys.modules["matplotlib.pyplot"].close("all")
    for w in caught:
        err.write(warnings.formatwarning(w.message, w.category, w.filename, w.lineno, w.line))
    return subprocess.CompletedProcess(["tpods", *args], rc, out.getvalue(), err.getvalue())


def main_rc(argv: list[str], capsys) -> tuple[int, str, list[str]]:
    """``tpods`` in process: (exit code, stdout, the non-blank stderr lines)."""
    from tpods.cli import main

    try:
        rc = main(argv)
    except SystemExit as exc:
        rc = exc.code
    out = capsys.readouterr()
    return rc, out.out, [ln for ln in out.err.splitlines() if ln.strip()]
