"""The CLI reference page, generated from ``tpods``'s argparse parsers so that it cannot
drift from them: every command and subcommand with its help text, as ``--help`` prints it.

``python -m docs_tools.cli_reference [--out FILE]`` writes it by hand; the site builds it
through :mod:`docs_tools.hooks`.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Iterator
from pathlib import Path

WIDTH = 100
"""Columns of the help text in the page (argparse reads ``COLUMNS``)."""


def _subparsers(parser: argparse.ArgumentParser) -> Iterator[tuple[str, str, argparse.ArgumentParser]]:
    """(name, one-line help, parser) of each direct subcommand, in the order registered."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: (a.help or "") for a in action._choices_actions}
            seen: set[int] = set()
            for name, sub in action.choices.items():
                if id(sub) in seen:  # an alias of a command already listed
                    continue
                seen.add(id(sub))
                yield name, helps.get(name, ""), sub


def walk(parser: argparse.ArgumentParser, path: tuple[str, ...] = ("tpods",), help_: str = ""
         ) -> Iterator[tuple[tuple[str, ...], str, argparse.ArgumentParser]]:
    """Every parser of the tree, depth first: (command path, one-line help, parser)."""
    yield path, help_, parser
    for name, sub_help, sub in _subparsers(parser):
        yield from walk(sub, (*path, name), sub_help)


def commands(parser: argparse.ArgumentParser | None = None) -> list[str]:
    """Every command path below ``tpods``, e.g. ``"tpods estimate batch"``."""
    return [" ".join(p) for p, _, _ in list(walk(parser or _parser()))[1:]]


def _parser() -> argparse.ArgumentParser:
    from tpods.cli import build_parser
    return build_parser()


def _help(parser: argparse.ArgumentParser) -> str:
    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = str(WIDTH)
    try:
        return parser.format_help().rstrip()
    finally:
        if old is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = old


def _anchor(path: tuple[str, ...]) -> str:
    return "-".join(path)


def page(parser: argparse.ArgumentParser | None = None) -> str:
    """The Markdown page: an index of every command, then each command's ``--help``."""
    parser = parser or _parser()
    tree = list(walk(parser))
    out = [
        "# Command-line reference",
        "",
        "Generated from the `tpods` parsers at every build of this site "
        "(`docs_tools/cli_reference.py`), so it says what `tpods COMMAND --help` says. "
        "User errors print one line (`tpods: error: ...`) and exit 2; "
        "the rules every command keeps: [what the toolkit never does](rules.md).",
        "",
        "## Commands",
        "",
    ]
    for path, help_, _ in tree[1:]:
        indent = "    " * (len(path) - 2)
        line = f"{indent}- [`{' '.join(path)}`](#{_anchor(path)})"
        out.append(line + (f": {help_}" if help_ else ""))
    for path, help_, sub in tree:
        depth = min(len(path) + 1, 4)
        out += ["", f"{'#' * depth} `{' '.join(path)}` {{ #{_anchor(path)} }}", ""]
        if help_:
            out += [help_[0].upper() + help_[1:] + ("" if help_.endswith(".") else "."), ""]
        out += ["```text", _help(sub), "```"]
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="write the CLI reference page")
    ap.add_argument("--out", help="the Markdown file (default: standard output)")
    args = ap.parse_args(argv)
    text = page()
    if args.out:
        Path(args.out).write_text(text)
    else:
        sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
