"""Partial runs (issue 16): recorders mark a run that did not end cleanly in its status
file, and every reader warns once on stderr, naming the folder and the status, and reads it.

The rule (docs/run-format.md): a ``status`` other than ``complete`` or ``success`` is partial.
"""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest

from common.runfolder import partial_status, read_run
from common.runwriter import run_status
from common.thrust_table import ThrustTable
from mocap_bridge.recorder import Recorder
from tpods.cli import main

PARTIAL = ("running", "incomplete", "aborted", "stopped", "failed")
WHOLE = ("complete", "success", None)


def _set_status(folder: Path, status: str | None, name: str = "run.json") -> None:
    f = folder / name
    meta = json.loads(f.read_text()) if f.exists() else {"kind": "test"}
    meta.pop("status", None)
    if status is not None:
        meta["status"] = status
    f.write_text(json.dumps(meta) + "\n")


def _warnings(err: str) -> list[str]:
    return [ln for ln in err.splitlines() if "partial run" in ln]


@pytest.fixture(scope="module")
def sim_run(tmp_path_factory) -> Path:
    run = tmp_path_factory.mktemp("sim") / "run"
    assert main(["sim", "--duration", "8", "--out", str(run)]) == 0
    return run


@pytest.fixture(scope="module")
def session_run(tmp_path_factory) -> Path:
    """A characterisation session folder (raw.csv as the session writes it, run.json)."""
    table = ThrustTable.default()
    rows, t, w = [], 0.0, 0
    for k in (1, 2):
        for d in range(10, 91, 20):
            for phase, step, val in (("zero", -1, 0.0), ("dwell", w, float(table.per_nozzle(d, k)))):
                for i in range(5):
                    rows.append((t, w, phase, step, k if step >= 0 else 0, d if step >= 0 else 0,
                                 val + 0.01 * (i - 2), 1))
                    t += 0.1
            w += 1
    run = tmp_path_factory.mktemp("bench") / "session"
    run.mkdir()
    pd.DataFrame(rows, columns=["t_s", "window", "phase", "step", "n_open", "duty_pct",
                                "reading_gf", "stable"]).to_csv(run / "raw.csv", index=False)
    return run


def test_the_rule():
    for s in PARTIAL:
        assert partial_status({"status": s}) == s
    for s in WHOLE:
        assert partial_status({} if s is None else {"status": s}) is None


@pytest.mark.parametrize("status", PARTIAL)
def test_estimate_batch_warns_once_on_a_partial_run(status, sim_run, capsys):
    _set_status(sim_run, status)
    assert main(["estimate", "batch", str(sim_run)]) == 0
    cap = capsys.readouterr()
    w = _warnings(cap.err)
    assert len(w) == 1, cap.err
    assert w[0].startswith(f"tpods: warning: {sim_run} is a partial run") and f"'{status}'" in w[0]
    assert "mass" in cap.out  # and it was read and estimated


@pytest.mark.parametrize("status", WHOLE)
def test_estimate_batch_is_quiet_on_a_whole_run(status, sim_run, capsys):
    _set_status(sim_run, status)
    assert main(["estimate", "batch", str(sim_run)]) == 0
    assert _warnings(capsys.readouterr().err) == []


def test_estimate_crlb_warns_once(sim_run, capsys):
    _set_status(sim_run, "running")
    assert main(["estimate", "crlb", str(sim_run)]) == 0
    assert len(_warnings(capsys.readouterr().err)) == 1


@pytest.mark.parametrize("status", [*PARTIAL, *WHOLE])
def test_bench_fit_warns_once_on_a_partial_session(status, session_run, tmp_path, capsys):
    _set_status(session_run, status)
    out = tmp_path / "table.toml"
    assert main(["bench", "fit", str(session_run), "--order", "3", "--out", str(out)]) == 0
    w = _warnings(capsys.readouterr().err)
    assert out.exists()
    if status in PARTIAL:
        assert len(w) == 1 and str(session_run) in w[0] and f"'{status}'" in w[0], w
    else:
        assert w == []


def test_a_refused_run_gets_the_error_only(sim_run, tmp_path, capsys):
    bad = tmp_path / "bad"
    bad.mkdir()
    for f in ("commands.csv", "run.json"):
        (bad / f).write_bytes((sim_run / f).read_bytes())
    _set_status(bad, "running")
    (bad / "poses.csv").write_text("t,x,y,psi\n0,0,0,nan\n")
    assert main(["estimate", "batch", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("tpods: error: ") and len(err.strip().splitlines()) == 1, err


def test_mocap_body_folder_takes_the_recording_status(sim_run, tmp_path, capsys):
    rec = tmp_path / "rec"
    body = rec / "tpods1"
    body.mkdir(parents=True)
    for f in ("commands.csv", "poses.csv"):
        (body / f).write_bytes((sim_run / f).read_bytes())
    _set_status(rec, "running", "recording.json")
    read_run(body)
    w = _warnings(capsys.readouterr().err)
    assert len(w) == 1 and str(body) in w[0] and "recording.json" in w[0], w
    _set_status(rec, "complete", "recording.json")
    read_run(body)
    assert _warnings(capsys.readouterr().err) == []


def test_mocap_recorder_status(tmp_path):
    def status(folder: Path) -> str:
        return json.loads((folder / "recording.json").read_text())["status"]

    rec = Recorder(tmp_path / "a")
    assert status(rec.out) == "running"  # a hard kill leaves this
    rec.close()
    assert status(rec.out) == "complete"
    with pytest.raises(RuntimeError), Recorder(tmp_path / "b") as rec:
        raise RuntimeError("crash")
    assert status(rec.out) == "incomplete"
    rec = Recorder(tmp_path / "c")
    rec.counters["write_errors"] = 3
    rec.close()
    assert status(rec.out) == "incomplete"


def test_run_status(tmp_path):
    f = tmp_path / "run.json"

    def status() -> str:
        return json.loads(f.read_text())["status"]

    with run_status(f, "test", seed=1) as meta:
        assert status() == "running" and meta["seed"] == 1
    assert status() == "complete"
    with pytest.raises(KeyboardInterrupt), run_status(f, "test"):
        raise KeyboardInterrupt
    assert status() == "aborted"
    with pytest.raises(ValueError), run_status(f, "test"):
        raise ValueError("bad")
    meta = json.loads(f.read_text())
    assert meta["status"] == "failed" and meta["error"] == "bad"
