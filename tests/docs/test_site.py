"""The documentation site: `mkdocs build --strict` passes with no warning, fails on a page
left out of the nav or a broken link, every relative link of the built site resolves, and
the generated CLI reference lists every subcommand."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from docs_tools.cli_reference import commands, page
from docs_tools.links import broken_links

ROOT = Path(__file__).resolve().parents[2]


def _build(config: Path, site: Path) -> subprocess.CompletedProcess:
    pytest.importorskip("mkdocs", reason="mkdocs not installed (make setup installs .[test,docs])")
    pytest.importorskip("material", reason="mkdocs-material not installed (the docs extra)")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1", "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-f", str(config),
                           "--site-dir", str(site)], cwd=config.parent, env=env,
                          capture_output=True, text=True, timeout=120)


@pytest.fixture(scope="module")
def built_site(tmp_path_factory) -> Path:
    site = tmp_path_factory.mktemp("site")
    proc = _build(ROOT / "mkdocs.yml", site)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "WARNING" not in proc.stdout + proc.stderr, proc.stdout + proc.stderr
    return site


def test_strict_build_passes_without_warnings(built_site):
    assert (built_site / "index.html").is_file()
    assert (built_site / "cli.html").is_file()
    assert (built_site / "changelog.html").is_file()


def test_every_relative_link_of_the_site_resolves(built_site):
    assert broken_links(built_site) == []


def test_cli_reference_in_the_site_lists_every_subcommand(built_site):
    html = (built_site / "cli.html").read_text()
    missing = [c for c in commands() if f'id="{c.replace(" ", "-")}"' not in html]
    assert not missing, missing


def test_cli_reference_covers_every_command_of_the_parser():
    names = commands()
    assert {"tpods estimate batch", "tpods import poses", "tpods demo", "tpods bench fit"} <= set(names)
    text = page()
    for name in names:
        assert f"## `{name}`" in text, name
    assert len(names) >= 40


def test_strict_build_fails_on_a_page_left_out_of_the_nav_and_a_broken_link(tmp_path):
    for name in ("docs", "docs_tools"):
        shutil.copytree(ROOT / name, tmp_path / name,
                        ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("mkdocs.yml", "CHANGELOG.md"):
        shutil.copy(ROOT / name, tmp_path / name)
    (tmp_path / "docs" / "orphan.md").write_text("# Orphan\n\nIn no nav.\n")
    (tmp_path / "docs" / "index.md").write_text(
        (ROOT / "docs" / "index.md").read_text() + "\n[gone](nowhere.md)\n")
    proc = _build(tmp_path / "mkdocs.yml", tmp_path / "site")
    out = proc.stdout + proc.stderr
    assert proc.returncode != 0, out
    assert "orphan.md" in out and "nowhere.md" in out, out


def test_link_check_finds_a_missing_file_and_a_missing_anchor(tmp_path):
    (tmp_path / "a.html").write_text('<h2 id="here">x</h2><a href="b.html">b</a>'
                                      '<a href="a.html#here">ok</a><a href="#gone">no</a>'
                                      '<img src="fig.png"><a href="https://example.org/x">out</a>')
    problems = broken_links(tmp_path)
    assert problems == ["a.html: b.html (no such file)", "a.html: #gone (no anchor #gone)",
                        "a.html: fig.png (no such file)"]
