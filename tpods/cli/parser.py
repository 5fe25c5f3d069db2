"""The ``tpods`` argument parser class and its command groups.

:class:`Parser` makes every argparse error one line (``tpods: error: ...``, exit 2);
:func:`group` adds a command group (``tpods NAME SUBCOMMAND``). The command modules
import these from here, so that none of them imports the package that registers them.
"""

from __future__ import annotations

import argparse


class Parser(argparse.ArgumentParser):
    """argparse parser whose errors are one line (usage goes to --help)."""

    def error(self, message: str) -> None:  # pragma: no cover - exercised via CLI tests
        # the documented contract: every user error is one line `tpods: error: ...`, exit 2
        self.exit(2, f"tpods: error: {message} (see '{self.prog} --help')\n")


def group(sub, name: str, help_text: str) -> argparse._SubParsersAction:
    """Add a command group (``tpods NAME ...``) and return its sub-parsers."""
    p = sub.add_parser(name, help=help_text, description=help_text)
    p.set_defaults(func=None, parser=p)
    g = p.add_subparsers(dest=f"{name}_command", metavar="SUBCOMMAND", parser_class=Parser)
    return g
