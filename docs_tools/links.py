"""Follows every relative link of a built site: each ``href``/``src`` of every HTML page
must name a file inside the site, and a ``#fragment`` on a link to a page an ``id`` in it.

``python -m docs_tools.links [SITE]`` prints what does not resolve (exit 1 if anything).
"""

from __future__ import annotations

import sys
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import unquote, urlsplit


class _Page(HTMLParser):
    def __init__(self) -> None:
        super().__init__(convert_charrefs=True)
        self.links: list[tuple[str, str]] = []  # (tag, url)
        self.ids: set[str] = set()

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if a.get("id"):
            self.ids.add(a["id"])
        if tag == "a" and a.get("name"):
            self.ids.add(a["name"])
        for key in ("href", "src"):
            if a.get(key) is not None and tag in ("a", "img", "link", "script", "source"):
                self.links.append((tag, a[key]))


def _parse(path: Path) -> _Page:
    p = _Page()
    p.feed(path.read_text(encoding="utf-8", errors="replace"))
    return p


def _relative(url: str) -> bool:
    parts = urlsplit(url)
    return not (parts.scheme or parts.netloc or url.startswith("/"))


def broken_links(site: Path) -> list[str]:
    """Every relative link of ``site``'s pages that does not resolve, as
    ``page: url (why)``; empty when all do."""
    site = Path(site).resolve()
    pages = sorted(site.rglob("*.html"))
    parsed = {p: _parse(p) for p in pages}
    problems: list[str] = []
    for page, doc in parsed.items():
        for tag, url in doc.links:
            if not url or not _relative(url) or url.startswith(("mailto:", "javascript:")):
                continue
            parts = urlsplit(url)
            target = page if not parts.path else (page.parent / unquote(parts.path)).resolve()
            where = f"{page.relative_to(site)}: {url}"
            if site not in target.parents and target != site:
                problems.append(f"{where} (outside the site)")
                continue
            if target.is_dir():
                target = target / "index.html"
            if not target.is_file():
                problems.append(f"{where} (no such file)")
                continue
            frag = unquote(parts.fragment)
            if tag == "a" and frag and target.suffix == ".html":
                ids = parsed[target].ids if target in parsed else _parse(target).ids
                if frag not in ids:
                    problems.append(f"{where} (no anchor #{frag})")
    return problems


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    site = Path(args[0] if args else "site")
    problems = broken_links(site)
    for p in problems:
        print(p)
    n = len(list(site.rglob("*.html")))
    print(f"{n} pages, {len(problems)} broken link(s)")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
