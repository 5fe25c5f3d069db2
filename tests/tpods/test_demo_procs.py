"""The demo's child-process helpers (tpods/demo_procs.py)."""

from __future__ import annotations

import subprocess
import sys

from tpods.demo_procs import child_failed


def test_a_failed_child_is_named_with_what_it_said(tmp_path):
    log = tmp_path / "play.log"
    with log.open("w") as f:
        proc = subprocess.Popen([sys.executable, "-c",
                                 "import sys; print('play: phase-sine for 40 s');"
                                 "print('tpods: error: tpods2 did not confirm OFF'); "
                                 "print('closing'); sys.exit(2)"], stdout=f, stderr=subprocess.STDOUT)
        proc.wait(30)
    err = str(child_failed("player", proc, log))
    assert err == (f"the player failed (exit 2: tpods: error: tpods2 did not confirm OFF; "
                   f"see {log})")


def test_a_missing_log_still_gives_the_exit_code(tmp_path):
    proc = subprocess.Popen([sys.executable, "-c", "raise SystemExit(3)"])
    proc.wait(30)
    assert str(child_failed("player", proc, tmp_path / "none.log")) == (
        f"the player failed (exit 3; see {tmp_path / 'none.log'})")
