"""``tpods fixture add|list``: a recording as a regression fixture (:mod:`tpods.fixtures`)."""

from __future__ import annotations

import argparse

from tpods.cli.parser import command, group


def register(sub) -> None:
    """Add ``tpods fixture`` to the `tpods` parser."""
    g = group(sub, "fixture", "recorded fixtures of the regression tests (runs/fixtures/)")
    p = command(
        g, "add", cmd_add, help="copy a recording into runs/fixtures/NAME and compute its goldens")
    p.add_argument("recording", metavar="RECORDING", help="the run folder, session folder or file")
    p.add_argument("--name", required=True, help="the fixture's folder name")
    p.add_argument("--root", default=None, metavar="DIR",
                   help="fixtures folder (default runs/fixtures of this checkout)")
    p.add_argument("--force", action="store_true", help="replace a fixture of that name")
    ls = g.add_parser("list", help="the fixtures and their kinds",
                      description="List the fixtures (folders with fixture.json) and their kinds.")
    ls.add_argument("--root", default=None, metavar="DIR",
                    help="fixtures folder (default runs/fixtures of this checkout)")
    ls.set_defaults(func=cmd_list)


def cmd_add(args: argparse.Namespace) -> int:
    """Copy a recording into runs/fixtures/NAME (or --root DIR/NAME): a run folder (poses.csv,
    commands.csv; with structure.toml a structure run), a bifilar swing (poses.csv,
    bifilar.json), a bench session (*.serial.jsonl with its run.json or session.json), a .pcap
    or a .mcap file. Writes README.md, fixture.json (the kind) and golden/values.json, computed
    with the functions the regression tests use (tests/regression/test_fixtures_generic.py
    replays every fixture against its golden)."""

    from tpods import fixtures

    root = args.root or fixtures.FIXTURES_ROOT
    kind = fixtures.detect_kind(args.recording)
    print(f"{args.recording}: {fixtures.KINDS[kind]}", flush=True)
    dest, kind, lines = fixtures.add_fixture(args.recording, args.name, root=root, force=args.force)
    for line in lines:
        print(line)
    size = sum(p.stat().st_size for p in dest.rglob("*") if p.is_file())
    print(f"added {dest} ({kind}, {size / 1e3:.0f} kB); `make test` checks it, `make golden` "
          "rewrites its goldens after a deliberate change")
    return 0


def cmd_list(args: argparse.Namespace) -> int:
    from tpods import fixtures

    for f in fixtures.list_fixtures(args.root or fixtures.FIXTURES_ROOT):
        meta = fixtures.read_fixture_json(f)
        print(f"{f.name:20s} {meta.get('kind', '?'):14s} {meta.get('added', '')}")
    return 0
