"""The ``tpods`` argument parser class, its command groups and their commands.

:class:`Parser` makes every argparse error one line (``tpods: error: ...``, exit 2);
:func:`group` adds a command group (``tpods NAME SUBCOMMAND``), :func:`command` one
command of a group with the function it runs (whose docstring is the command's description).
The command modules import these from here, so that none of them imports the package that
registers them.
"""

from __future__ import annotations

import argparse
import inspect
from collections.abc import Callable
from typing import Any


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


def command(g: argparse._SubParsersAction, name: str, func: Callable[[argparse.Namespace], Any],
            help: str, description: str | None = None, **kwargs: Any) -> argparse.ArgumentParser:
    """Add the command ``name`` to the group ``g`` that runs ``func(args)``; return its
    parser, to add the options to. ``help`` is its line in the group's list; ``description``,
    the top of its --help, is by default ``func``'s docstring (one text for both; argparse
    folds its line breaks); ``kwargs`` as for ``add_parser`` (``epilog``)."""
    if description is None:
        description = inspect.cleandoc(func.__doc__ or "")
    p = g.add_parser(name, help=help, description=description, **kwargs)
    p.set_defaults(func=func)
    return p
