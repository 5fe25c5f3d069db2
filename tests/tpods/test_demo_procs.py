"""The demo's child-process helpers (tpods/demo/procs.py)."""

from __future__ import annotations

import subprocess
import sys

from tpods.demo.procs import child_failed, wait_recorded


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


def _child_writing(run_json, text: str, then_s: float) -> subprocess.Popen:
    """A child that writes ``text`` into ``run_json`` (atomically) and then lives
    ``then_s`` more seconds: a live estimator sealing its recording, then finishing."""
    code = ("import os, sys, time; p = sys.argv[1]; open(p + '.tmp', 'w').write(sys.argv[2]);"
            f" os.replace(p + '.tmp', p); time.sleep({then_s})")
    return subprocess.Popen([sys.executable, "-c", code, str(run_json), text])


def test_waiting_for_the_seal_returns_while_the_estimator_still_runs(tmp_path):
    run_json = tmp_path / "run.json"
    run_json.write_text('{"status": "running"}')  # written at its start: not sealed yet
    proc = _child_writing(run_json, '{"status": "running", "data_complete": true}', 30)
    try:
        assert wait_recorded(tmp_path, proc, timeout_s=30) is True
        assert proc.poll() is None
    finally:
        proc.kill()
        proc.wait(30)


def test_an_estimator_that_ends_unsealed_ends_the_wait(tmp_path):
    proc = _child_writing(tmp_path / "run.json", '{"status": "failed"}', 0)
    assert wait_recorded(tmp_path, proc, timeout_s=30) is False
    assert proc.returncode == 0
