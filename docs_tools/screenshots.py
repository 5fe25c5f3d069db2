"""Screenshots of the built site in headless Chromium, and its links checked.

Serves ``site/`` on localhost, opens the home page and one reference page (the CLI
reference) with Debian's ``chromium`` and writes a PNG of each; then follows every
relative link of the site (:mod:`docs_tools.links`). Run by hand after ``make docs``::

    python -m docs_tools.screenshots [--site site] [--out runs/docs-screenshots]

(``apt-get install chromium`` where it is missing). The tests run the link check only.
"""

from __future__ import annotations

import argparse
import functools
import http.server
import shutil
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

from docs_tools.links import broken_links

PAGES = {"home": "index.html", "cli-reference": "cli.html"}
"""The pages shot: name of the PNG -> page of the site."""

CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                  "--no-first-run", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync", "--hide-scrollbars"]


def chromium() -> str | None:
    """Path of the Chromium executable, or None."""
    for name in ("chromium", "chromium-browser", "google-chrome"):
        found = shutil.which(name)
        if found:
            return found
    return None


class _Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):  # no request log on stderr
        pass


def serve(site: Path) -> tuple[http.server.ThreadingHTTPServer, str]:
    """Serve ``site`` on a free localhost port in a daemon thread; (server, base URL)."""
    handler = functools.partial(_Quiet, directory=str(site))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server, f"http://127.0.0.1:{server.server_address[1]}/"


def screenshot(url: str, png: Path, exe: str, size: str = "1280,900", timeout_s: float = 60) -> Path:
    """One PNG of ``url`` at ``size`` (width,height in pixels)."""
    png.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as profile:
        subprocess.run([exe, *CHROMIUM_FLAGS, f"--user-data-dir={profile}",
                        f"--screenshot={png.resolve()}", f"--window-size={size}", url],
                       check=True, timeout=timeout_s, capture_output=True)
    if not png.is_file() or png.stat().st_size == 0:
        raise RuntimeError(f"chromium wrote no screenshot of {url}")
    return png


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--site", default="site", help="the built site (default site/, make docs)")
    ap.add_argument("--out", default="runs/docs-screenshots", help="folder of the PNGs")
    args = ap.parse_args(argv)
    site = Path(args.site)
    if not (site / "index.html").is_file():
        print(f"no built site in {site}/: run make docs first", file=sys.stderr)
        return 2
    problems = broken_links(site)
    for p in problems:
        print(f"broken link: {p}")
    print(f"links: {len(problems)} broken in {len(list(site.rglob('*.html')))} pages")
    exe = chromium()
    if exe is None:
        print("no chromium on PATH (apt-get install chromium): screenshots skipped", file=sys.stderr)
        return 1 if problems else 0
    server, base = serve(site)
    try:
        for name, page in PAGES.items():
            png = screenshot(base + page, Path(args.out) / f"{name}.png", exe)
            print(f"wrote {png} ({png.stat().st_size} bytes) of {page}")
    finally:
        server.shutdown()
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
