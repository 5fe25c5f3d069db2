"""The one output policy (common/outputs.py) across every command that writes (issue 16).

- an existing non-empty --out (an existing file for a file output) is refused, one line,
  exit 2, nothing in it changed; with --force it is replaced;
- --out '' / at a file / under a file: exit 2, one line, no traceback;
- an interrupted atomic write leaves the old folder byte-identical and no temporary folder;
- a temporary left by a killed command is removed by the next one (if its PID is dead);
- the --out rule: a path ending in .toml, .json or .mcap names that file, anything else a
  folder. Commands with one main file write just it to FILE.json / FILE.toml, or it and the
  rest into a folder; commands that write a folder refuse a file name; .mcap is refused except by the MCAP
  writers (mocap record, estimate live, export mcap);
- long commands (bench emulate --log-dir, run plant --truth-out) refuse a bad output at
  their start, not after the run.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from common.errors import UserError
from common.outputs import ResultFile, ResultFolder, check_folder, stream_folder
from tpods.cli import main

# Every command that writes, with the least it needs to reach its output check (the check
# comes first, so missing inputs and devices are never reached). OUT stands for the output.
FOLDER_COMMANDS = {
    "sim": ["sim", "--duration", "2", "--out", "OUT"],
    "design": ["design", "--out", "OUT"],
    "estimate batch": ["estimate", "batch", "no-such-run", "--out", "OUT"],
    "estimate crlb": ["estimate", "crlb", "no-such-run", "--out", "OUT"],
    "estimate montecarlo": ["estimate", "montecarlo", "--out", "OUT"],
    "report table3": ["report", "table3", "--out", "OUT"],
    "report ekf": ["report", "ekf", "--out", "OUT"],
    "report realism": ["report", "realism", "--out", "OUT"],
    "calibrate bifilar": ["calibrate", "bifilar", "--mass", "0.72", "--spacing", "0.1", "--length",
                          "1.0", "--times", "16.4,16.5", "--out", "OUT"],
    "bench characterize": ["bench", "characterize", "--valves", "no-dev", "--scale", "no-dev",
                           "--out", "OUT"],
    "mocap record": ["mocap", "record", "--out", "OUT"],
    "run play": ["run", "play", "--valves", "no-dev", "--duration", "1", "--out", "OUT"],
    "run plant": ["run", "plant", "--truth-out", "OUT"],
    "bench emulate": ["bench", "emulate", "--log-dir", "OUT"],
    "estimate live": ["estimate", "live", "--out", "OUT"],
    "demo": ["demo", "--out", "OUT"],
}
# Commands whose result is one main file: --out FILE.<suffix> writes just that file.
FILE_COMMANDS = {
    "bench fit": ["bench", "fit", "no-such-run", "--out", "OUT"],
    "estimate batch": FOLDER_COMMANDS["estimate batch"],
    "estimate crlb": FOLDER_COMMANDS["estimate crlb"],
    "estimate montecarlo": FOLDER_COMMANDS["estimate montecarlo"],
    "calibrate bifilar": FOLDER_COMMANDS["calibrate bifilar"],
}
MAIN_FILE = {"bench fit": "thrust_table.toml", "estimate batch": "estimate.json",
             "estimate crlb": "crlb.json", "estimate montecarlo": "montecarlo.json",
             "calibrate bifilar": "result.json"}
# Commands that write a folder (a run folder, a report, logs) and nothing else.
FOLDER_ONLY = sorted(set(FOLDER_COMMANDS) - set(FILE_COMMANDS))


def _argv(template: list[str], out: Path | str) -> list[str]:
    return [str(out) if a == "OUT" else a for a in template]


def _snapshot(folder: Path) -> dict[str, tuple[bytes, int]]:
    return {str(p.relative_to(folder)): (p.read_bytes(), p.stat().st_mtime_ns)
            for p in sorted(folder.rglob("*")) if p.is_file()}


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err
    assert err.startswith("tpods: error: "), err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    return err


def _old_results(tmp_path: Path) -> Path:
    old = tmp_path / "results"
    old.mkdir()
    (old / "poses.csv").write_text("t,x,y,psi\n0,0,0,0\n")
    (old / "run.json").write_text('{"kind": "old"}\n')
    return old


def _no_temporaries(parent: Path) -> None:
    left = [p.name for p in parent.iterdir() if ".tmp-" in p.name or ".old-" in p.name]
    assert not left, left


@pytest.mark.parametrize("name", sorted(FOLDER_COMMANDS))
def test_existing_folder_is_refused_and_untouched(name, tmp_path, capsys):
    old = _old_results(tmp_path)
    before = _snapshot(old)
    assert main(_argv(FOLDER_COMMANDS[name], old)) == 2
    err = _one_error_line(capsys)
    assert f"{old} already holds poses.csv, run.json; add --force" in err, err
    assert _snapshot(old) == before
    _no_temporaries(tmp_path)


@pytest.mark.parametrize("name", sorted(FILE_COMMANDS))
def test_existing_file_is_refused_and_untouched(name, tmp_path, capsys):
    f = tmp_path / ("earlier" + Path(MAIN_FILE[name]).suffix)
    f.write_text("# an earlier fit\n")
    before = (f.read_bytes(), f.stat().st_mtime_ns)
    assert main(_argv(FILE_COMMANDS[name], f)) == 2
    assert f"{f} already exists; add --force" in _one_error_line(capsys)
    assert (f.read_bytes(), f.stat().st_mtime_ns) == before


# a folder output: '', an existing file, a path under a file; a file output: '', a path
# under a file, an existing folder named like a file (an existing file: refused above)
IMPOSSIBLE = ([("folder", n, c) for n in sorted(FOLDER_COMMANDS) for c in ("empty", "at-file", "under-file")]
              + [("file", n, c) for n in sorted(FILE_COMMANDS) for c in ("empty", "under-file", "at-folder")])


@pytest.mark.parametrize(("kind", "name", "case"), IMPOSSIBLE)
def test_impossible_outputs_are_one_line(kind, name, case, tmp_path, capsys):
    table = FILE_COMMANDS[name] if kind == "file" else FOLDER_COMMANDS[name]
    suffix = Path(MAIN_FILE[name]).suffix if kind == "file" else ""
    a_file = tmp_path / "a_file"
    a_file.write_text("x\n")
    (tmp_path / f"a_folder{suffix}").mkdir()
    out = {"empty": "", "at-file": a_file, "under-file": a_file / "sub" / f"out{suffix}",
           "at-folder": tmp_path / f"a_folder{suffix}"}[case]
    argv = _argv(table, out)
    assert main(argv + ["--force"]) == 2
    err = _one_error_line(capsys)
    assert ("is empty" in err) if case == "empty" else (str(out) in err), err
    assert a_file.read_text() == "x\n"


def test_sim_force_replaces_the_folder_whole(tmp_path, capsys):
    old = _old_results(tmp_path)
    (old / "thrusts.csv").write_text("stale\n")  # would take precedence if left behind
    assert main(["sim", "--duration", "2", "--out", str(old), "--force"]) == 0
    names = {p.name for p in old.iterdir()}
    assert {"poses.csv", "commands.csv", "run.json", "truth.csv"} <= names
    assert "thrusts.csv" not in names and '"simulation"' in (old / "run.json").read_text()
    _no_temporaries(tmp_path)


def test_interrupted_sim_leaves_the_old_folder(tmp_path, capsys, monkeypatch):
    import estimator.plant.sim as sim

    real = sim.write_sim_run

    def half_then_fail(res, out, *a, **k):
        real(res, out, *a, **k)
        (Path(out) / "poses.csv").write_text("t,x,y,psi\n0,")  # truncated
        raise KeyboardInterrupt

    monkeypatch.setattr(sim, "write_sim_run", half_then_fail)
    old = _old_results(tmp_path)
    before = _snapshot(old)
    assert main(["sim", "--duration", "2", "--out", str(old), "--force"]) == 130
    assert _snapshot(old) == before
    _no_temporaries(tmp_path)
    # and with no old folder: no new one either
    new = tmp_path / "new"
    assert main(["sim", "--duration", "2", "--out", str(new)]) == 130
    assert not new.exists()
    _no_temporaries(tmp_path)


def test_estimate_batch_force_and_interrupt(tmp_path, capsys, monkeypatch):
    run = tmp_path / "run"
    assert main(["sim", "--duration", "8", "--out", str(run)]) == 0
    old = _old_results(tmp_path)
    before = _snapshot(old)
    import estimator.reports.plots.batch as plots_batch

    def fail(*a, **k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(plots_batch, "plot_residuals", fail)
    with pytest.raises(OSError):
        main(["estimate", "batch", str(run), "--out", str(old), "--force"])
    assert _snapshot(old) == before
    _no_temporaries(tmp_path)
    monkeypatch.undo()
    capsys.readouterr()
    assert main(["estimate", "batch", str(run), "--out", str(old), "--force"]) == 0
    assert {p.name for p in old.iterdir()} == {"estimate.json", "residuals.csv", "residuals.png",
                                           "poses_fit.png"}
    _no_temporaries(tmp_path)


def test_force_never_replaces_the_input_run(tmp_path, capsys):
    run = _old_results(tmp_path)
    before = _snapshot(run)
    for cmd in ("batch", "crlb"):
        assert main(["estimate", cmd, str(run), "--out", str(run), "--force"]) == 2
        assert "would replace the input" in _one_error_line(capsys)
    assert _snapshot(run) == before


def test_calibrate_bifilar_force(tmp_path, capsys):
    old = _old_results(tmp_path)
    argv = _argv(FOLDER_COMMANDS["calibrate bifilar"], old)
    assert main(argv + ["--force"]) == 0
    assert "result.json" in {p.name for p in old.iterdir()} and not (old / "poses.csv").exists()
    assert str(old / "result.json") in capsys.readouterr().out


def test_result_file_interrupted_and_forced(tmp_path):
    f = tmp_path / "thrust_table.toml"
    f.write_text("old\n")
    with pytest.raises(UserError, match="already exists"):
        ResultFile(f)
    out = ResultFile(f, force=True)
    with pytest.raises(RuntimeError), out.writing() as tmp:
        tmp.write_text("half")
        raise RuntimeError
    assert f.read_text() == "old\n" and sorted(p.name for p in tmp_path.iterdir()) == [f.name]
    with out.writing() as tmp:
        tmp.write_text("new\n")
    assert f.read_text() == "new\n" and sorted(p.name for p in tmp_path.iterdir()) == [f.name]


def test_result_folder_rechecks_and_maps_paths(tmp_path):
    target = tmp_path / "a" / "b"  # missing parents are created at the end
    out = ResultFolder(target)
    assert not (tmp_path / "a").exists()
    with out.writing() as d:
        (d / "x.txt").write_text("1")
        assert out.final(d / "x.txt") == target / "x.txt"
    assert (target / "x.txt").read_text() == "1"
    # something appeared while the command worked: still refused without --force
    late = tmp_path / "late"
    out = ResultFolder(late)
    late.mkdir()
    (late / "other.csv").write_text("z")
    with pytest.raises(UserError, match="already holds other.csv"), out.writing():
        pass
    assert (late / "other.csv").read_text() == "z"


def test_stream_folder_refuses_then_empties_with_force(tmp_path):
    old = _old_results(tmp_path)
    with pytest.raises(UserError, match="add --force"):
        stream_folder(old, force=False)
    assert stream_folder(old, force=True) == old and not any(old.iterdir())
    assert check_folder(old, force=False) == old  # an empty folder is fine


def test_long_listing_is_shortened(tmp_path):
    d = tmp_path / "many"
    d.mkdir()
    for i in range(9):
        (d / f"f{i}.csv").write_text("")
    with pytest.raises(UserError) as e:
        check_folder(d, force=False)
    assert "f0.csv, f1.csv, f2.csv, f3.csv, ... (9 entries)" in str(e.value)


# ---- stale temporaries: a command killed outright (SIGKILL) leaves .NAME.tmp-PID behind

def _dead_pid() -> int:
    import subprocess
    import sys

    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def _stale_tmp(parent: Path, name: str, pid: int, kind: str = "tmp") -> Path:
    tmp = parent / f".{name}.{kind}-{pid}"
    tmp.mkdir()
    (tmp / "poses.csv").write_text("t,x,y,psi\n0,")  # half written when killed
    return tmp


def test_a_stale_temporary_is_removed_and_said(tmp_path, capsys):
    pid = _dead_pid()
    tmp = _stale_tmp(tmp_path, "results", pid)
    other = _stale_tmp(tmp_path, "another", pid)  # not this command's output: left alone
    assert main(["sim", "--duration", "2", "--out", str(tmp_path / "results")]) == 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("tpods: warning: removed "), err
    assert str(tmp) in err and f"process {pid}" in err
    assert not tmp.exists() and other.exists() and (tmp_path / "results" / "run.json").exists()


def test_the_temporary_of_a_running_process_is_left_alone(tmp_path, capsys):
    import subprocess
    import sys

    p = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        tmp = _stale_tmp(tmp_path, "results", p.pid)
        assert main(["sim", "--duration", "2", "--out", str(tmp_path / "results")]) == 0
        assert tmp.exists() and "removed" not in capsys.readouterr().err
    finally:
        p.kill()
        p.wait()


def test_killed_between_the_renames_restores_the_old_folder(tmp_path, capsys):
    pid = _dead_pid()
    old = _stale_tmp(tmp_path, "results", pid, "old")  # the old results, moved aside
    (old / "poses.csv").write_text("t,x,y,psi\n0,0,0,0\n")
    new = _stale_tmp(tmp_path, "results", pid)          # the new ones, never renamed
    out = tmp_path / "results"
    assert main(["sim", "--duration", "2", "--out", str(out)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 3, lines
    assert lines[0].startswith(f"tpods: warning: restored {out} from .results.old-{pid}")
    assert lines[1].startswith(f"tpods: warning: removed {new}")
    assert lines[2].startswith(f"tpods: error: {out} already holds poses.csv; add --force")
    assert (out / "poses.csv").read_text() == "t,x,y,psi\n0,0,0,0\n" and not old.exists()
    _no_temporaries(tmp_path)


def test_stale_old_beside_a_replaced_folder_is_removed(tmp_path, capsys):
    pid = _dead_pid()
    out = _old_results(tmp_path)
    old = _stale_tmp(tmp_path, "results", pid, "old")
    stream_folder(out, force=True)
    assert not old.exists() and f"removed {old}" in capsys.readouterr().err


def test_stale_file_temporary_is_removed(tmp_path, capsys):
    pid = _dead_pid()
    tmp = tmp_path / f".thrust_table.tmp-{pid}.toml"
    tmp.write_text("half")
    out = ResultFile(tmp_path / "thrust_table.toml")
    with out.writing() as t:
        t.write_text("unit = 'gf'\n")
    assert not tmp.exists() and f"removed {tmp}" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["thrust_table.toml"]


# ---- the --out rule: FILE.toml / FILE.json / FILE.mcap is that file, anything else a folder

def write_session(run: Path) -> Path:
    """A characterisation session folder (raw.csv as the session writes it) that fits."""
    import pandas as pd

    from common.thrust_table import ThrustTable

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
    run.mkdir(parents=True)
    pd.DataFrame(rows, columns=["t_s", "window", "phase", "step", "n_open", "duty_pct",
                                "reading_gf", "stable"]).to_csv(run / "raw.csv", index=False)
    return run


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> dict[str, Path]:
    base = tmp_path_factory.mktemp("inputs")
    assert main(["sim", "--duration", "8", "--out", str(base / "run")]) == 0
    return {"RUN": base / "run", "SESSION": write_session(base / "session")}


# what each command needs to run for real, and the files a folder output receives besides
# the main file (MAIN_FILE)
REAL = {
    "estimate batch": (["estimate", "batch", "RUN", "--out", "OUT"],
                       {"residuals.csv", "residuals.png", "poses_fit.png"}),
    "estimate batch ekf": (["estimate", "batch", "RUN", "--method", "ekf", "--out", "OUT"],
                           {"history.csv", "errors.png"}),
    "estimate crlb": (["estimate", "crlb", "RUN", "--out", "OUT"], {"sensitivities.png"}),
    "estimate montecarlo": (["estimate", "montecarlo", "--runs", "3", "--duration", "3", "--out", "OUT"],
                            {"history.csv", "runs.csv", "mc_runs.png", "mc_averages.png"}),
    "calibrate bifilar": (FOLDER_COMMANDS["calibrate bifilar"], {"budget.png"}),
    "bench fit": (["bench", "fit", "SESSION", "--order", "3", "--out", "OUT"],
                  {"thrust_table_orders.png", "thrust_table_timeseries.png"}),
}


def _real_argv(name: str, out: Path, inputs: dict[str, Path]) -> list[str]:
    return [str(inputs[a]) if a in inputs else a for a in _argv(REAL[name][0], out)]


def _main_file(name: str) -> str:
    return MAIN_FILE[name.removesuffix(" ekf")]


@pytest.mark.parametrize("name", sorted(REAL))
def test_a_file_name_writes_just_that_file(name, inputs, tmp_path, capsys):
    main_file = _main_file(name)
    out = tmp_path / "results" / ("mine" + Path(main_file).suffix)  # missing parents are made
    assert main(_real_argv(name, out, inputs)) == 0
    # bench fit keeps its plots beside the table (--plot-dir moves them), as it always did
    beside = {"mine_orders.png", "mine_timeseries.png"} if name == "bench fit" else set()
    assert {p.name for p in (tmp_path / "results").iterdir()} == {out.name} | beside
    text = out.read_text()
    if main_file == "thrust_table.toml":
        from common.thrust_table import ThrustTable

        assert sorted(ThrustTable.load(out).coefficients) == [1, 2]
    else:
        import json

        assert isinstance(json.loads(text), dict) and len(text) > 50
    assert str(out) in capsys.readouterr().out  # "wrote <out>", nothing else claimed
    _no_temporaries(tmp_path / "results")


@pytest.mark.parametrize("name", sorted(REAL))
def test_any_other_name_is_a_folder_of_the_files(name, inputs, tmp_path, capsys):
    out = tmp_path / "results.v2"  # a suffix outside the rule: still a folder
    assert main(_real_argv(name, out, inputs)) == 0
    assert {p.name for p in out.iterdir()} == {_main_file(name)} | REAL[name][1]
    _no_temporaries(tmp_path)


# a file name of the wrong kind for a main-file command: (command, --out name, message)
WRONG_FILE = ([(n, f"x{s}", f"names a {s} file; tpods {n} writes {MAIN_FILE[n]}")
               for n in sorted(FILE_COMMANDS) for s in (".json", ".toml")
               if s != Path(MAIN_FILE[n]).suffix]
              + [(n, "x.mcap", f"tpods {n} does not write MCAP (only tpods mocap record, "
                  f"tpods estimate live and tpods export mcap do); it writes {MAIN_FILE[n]}")
                 for n in sorted(FILE_COMMANDS)])


@pytest.mark.parametrize(("name", "out", "message"), WRONG_FILE)
def test_a_main_file_command_refuses_another_file_kind(name, out, message, tmp_path, capsys):
    path = tmp_path / out
    assert main(_argv(FILE_COMMANDS[name], path)) == 2
    err = _one_error_line(capsys)
    assert err.startswith(f"tpods: error: --out {path}") and message in err, err
    assert not any(tmp_path.iterdir())


MCAP_RECORDERS = {"mocap record", "estimate live"}  # --out X.mcap: the streams in MCAP (tests/common/test_mcap.py)


@pytest.mark.parametrize("suffix", [".json", ".toml", ".mcap", ".JSON"])
@pytest.mark.parametrize("name", FOLDER_ONLY)
def test_a_folder_command_refuses_a_file_name(name, suffix, tmp_path, capsys):
    if suffix == ".mcap" and name in MCAP_RECORDERS:
        pytest.skip(f"tpods {name} writes an --out X.mcap")
    option = {"run plant": "--truth-out", "bench emulate": "--log-dir"}.get(name, "--out")
    path = tmp_path / f"x{suffix}"
    assert main(_argv(FOLDER_COMMANDS[name], path)) == 2
    err = _one_error_line(capsys)
    assert err.startswith(f"tpods: error: {option} {path}"), err
    if suffix == ".mcap":
        assert f"tpods {name} does not write MCAP" in err and "writes a folder" in err, err
    else:
        assert f"names a file; tpods {name} writes a folder" in err, err
    assert not any(tmp_path.iterdir())


def test_bench_fit_never_replaces_its_session(inputs, tmp_path, capsys):
    session = inputs["SESSION"]
    assert main(["bench", "fit", str(session), "--out", str(session), "--force"]) == 2
    assert "would replace the input" in _one_error_line(capsys)
    assert (session / "raw.csv").exists()


# ---- long commands check their output before they run, not at their end

@pytest.mark.parametrize("argv", [
    ["bench", "emulate", "--duration", "60", "--log-dir"],
    ["run", "plant", "--duration", "60", "--truth-out"],
])
@pytest.mark.parametrize("case", ["a-file", "under-a-file", "a-json-name"])
def test_long_commands_refuse_their_output_at_the_start(argv, case, tpods_exe, tmp_path):
    import time

    from tests.support.cli import run_in_process

    a_file = tmp_path / "a_file"
    a_file.write_text("x\n")
    out = {"a-file": a_file, "under-a-file": a_file / "logs", "a-json-name": tmp_path / "logs.json"}[case]
    t0 = time.monotonic()
    r = run_in_process(*argv, str(out))
    assert r.returncode == 2 and time.monotonic() - t0 < 20  # not after the 60 s run
    assert r.stderr.startswith(f"tpods: error: {argv[-1]} {out}") and r.stderr.count("\n") == 1, r.stderr
    assert r.stdout == ""  # nothing served, nothing simulated
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file"] and a_file.read_text() == "x\n"
