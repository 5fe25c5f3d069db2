"""A library's warning reaches the user as one short line naming the library, not as an
absolute path into the installed package with a source line."""

from __future__ import annotations

import subprocess
import sys


def test_matplotlib_warning_is_short():
    code = ("import warnings, matplotlib\n"
            "from tpods.cli import short_library_warnings\n"
            "short_library_warnings(); short_library_warnings()\n"
            "f = matplotlib.__file__.replace('__init__.py', 'figure.py')\n"
            "warnings.warn_explicit('Tight layout not applied', UserWarning, f, 10)\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert r.stderr.strip() == "tpods: warning: (matplotlib) Tight layout not applied"


def test_own_warnings_keep_their_place():
    code = ("import warnings\n"
            "from tpods.cli import short_library_warnings\n"
            "short_library_warnings()\n"
            "warnings.warn('own')\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert "UserWarning: own" in r.stderr and "tpods: warning" not in r.stderr
