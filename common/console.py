"""A live status line for long-running commands (bridge, recorder, live estimator)."""

from __future__ import annotations

import sys


class Console:
    """One status line on stderr: rewritten in place on a terminal, one line per update
    otherwise (logs); ``end()`` finishes the line."""

    def __init__(self, quiet: bool) -> None:
        self.quiet = quiet
        self.tty = sys.stderr.isatty()
        self.dirty = False

    def show(self, line: str) -> None:
        if self.quiet:
            return
        if self.tty:
            sys.stderr.write("\r" + line[:200] + "\x1b[K")
            self.dirty = True
        else:
            sys.stderr.write(line + "\n")
        sys.stderr.flush()

    def end(self) -> None:
        if self.dirty:
            sys.stderr.write("\n")
            self.dirty = False
