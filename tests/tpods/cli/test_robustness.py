"""Every case of issue 16's "Found" list in one table (the CLI robustness suite, table part).

A row either runs the case here (argv, the input files it needs, the expected exit status and
a substring of the one-line message, or of the output for status 0), or points at the test
that already covers it (``see``: checked to exist, so a renamed test breaks this table, not
the coverage). Cases that still fail are marked xfail with their FINDING number (the property
suite, test_properties.py, keeps the same examples out of its strategies); drop the mark when
the fix lands. Runs in-process through the harness of test_properties.py.
"""

from __future__ import annotations

import contextlib
import io
import json
import re
from pathlib import Path

import pytest

from tests.tpods.cli.test_properties import check, run_cli
from tpods.cli import main

ROOT = Path(__file__).resolve().parents[3]

# A row: (issue text, argv, files, status, needle). In argv and in the files' text, RUN is a
# valid 3 s simulated run (copied per test) and TMP the test's folder. ``files`` maps a path
# under TMP to its text, or to ("lines-of", FILE, EDIT) for an edited copy of a RUN file.
RUN_ROWS = [
    ("decimal commas in --readings-from are refused, not read as two readings",
     ["calibrate", "mass", "--readings-from", "TMP/r.txt"], {"r.txt": "720,1\n720,3\n"},
     2, "a decimal comma"),
    ("a BOM in a readings file is read", ["calibrate", "mass", "--readings-from", "TMP/r.txt",
                                           "--json"], {"r.txt": "\ufeff720.1\n720.3 g\n"}, 0,
     '"n_readings": 2'),
    ("calibrate combine: a misspelled key is an error naming the nearest",
     ["calibrate", "combine", "TMP/p.toml"],
     {"p.toml": '[[part]]\nname = "A"\nmass_kg = 0.72\nizz_kgm2 = 1.2e-3\nposition_m = [0, 0]\n'
                'mass_sigma = 0.001\n'}, 2, "did you mean 'mass_sigma_kg'"),
    ("--spacing 10 (cm typed as m) warns", ["calibrate", "bifilar", "--mass", "0.72", "--spacing",
                                            "10", "--length", "1.0", "--times", "20.1,20.2"],
     {}, 0, "cm or mm"),
    ("a thrust table without unit is refused", ["estimate", "batch", "RUN", "--thrust-table",
                                                "TMP/t.toml"],
     {"t.toml": "duty_range = [10.0, 90.0]\n[nozzles.1]\ncoefficients = [-9.0692, 1.0439, "
                "-0.0128, 7.88e-5]\n"}, 2, "no unit"),
    ("a table negative over its duty range is refused", ["estimate", "batch", "RUN",
                                                         "--thrust-table", "TMP/t.toml"],
     {"t.toml": 'unit = "gf"\nduty_range = [10.0, 90.0]\n[nozzles.1]\ncoefficients = [-50.0, '
                '0.1]\n'}, 2, "negative"),
    ("a gf table labelled N warns naming the unit", ["estimate", "batch", "RUN", "--thrust-table",
                                                     "TMP/t.toml"],
     {"t.toml": ("lines-of", ROOT / "common" / "data" / "table2_60psi.toml",
                 lambda s: s.replace('unit = "gf"', 'unit = "N"'))}, 0, "thrust table in the wrong unit"),
    ("all valves closed: not called converged, names why", ["estimate", "batch", "TMP/closed"],
     {"closed/poses.csv": ("lines-of", "RUN/poses.csv", None),
      "closed/commands.csv": ("lines-of", "RUN/commands.csv",
                              lambda s: re.sub(r"(?m)^([^,\n]+),.*$", r"\1,0,0,0,0", s)
                              .replace("t,0,0,0,0", "t,d1,d2,d3,d4"))}, 0, "no thrust"),
    ("yaw in degrees: one line naming the cause, not a LinAlgError traceback", ["estimate", "batch", "TMP/deg"],
     {"deg/commands.csv": ("lines-of", "RUN/commands.csv", None),
      "deg/poses.csv": ("lines-of", "RUN/poses.csv",
                        lambda s: "\n".join([s.splitlines()[0]] + [
                            ",".join(c[:3] + [repr(float(c[3]) * 57.29577951308232)])
                            for c in (ln.split(",") for ln in s.splitlines()[1:])]) + "\n")},
     2, "yaw in degrees instead of radians"),
    ("text in a poses file is one line naming file and line", ["estimate", "batch", "TMP/txt"],
     {"txt/commands.csv": ("lines-of", "RUN/commands.csv", None),
      "txt/poses.csv": ("lines-of", "RUN/poses.csv", lambda s: s.replace("\n0.025,", "\nabc,", 1))},
     2, "poses.csv: line"),
    ("characterize --nozzles 5 is refused before a device or a folder", [
        "bench", "characterize", "--valves", "loop://", "--scale", "loop://", "--nozzles", "5",
        "--out", "TMP/ch"], {}, 2, "--nozzles 5"),
    ("--window 10,5 reversed is refused naming why", ["estimate", "batch", "RUN", "--window",
                                                      "10,5"], {}, 2, "end must follow its start"),
    ("crlb: a negative --pose-rate is an option error", ["estimate", "crlb", "RUN/commands.csv",
                                                         "--pose-rate", "-5"], {}, 2,
     "--pose-rate"),
    ("--seed -5 is one line, not numpy's ValueError",
     ["sim", "--duration", "1", "--seed", "-5", "--out", "TMP/o"], {}, 2, "--seed"),
    ("--amplitude 80 names the option", ["sim", "--duration", "1", "--amplitude", "80",
                                         "--out", "TMP/o"], {}, 2, "--amplitude"),
    ("--duration 1e9 is refused before allocating",
     ["sim", "--duration", "1e9", "--out", "TMP/o"], {}, 2, "--duration 1e9 s"),
    ("--cmd-rate 1e9 is refused before allocating",
     ["sim", "--duration", "3", "--cmd-rate", "1e9", "--out", "TMP/o"], {}, 2, "lower --cmd-rate"),
    ("crlb --pose-rate 1e7 does not hang silently",
     ["estimate", "crlb", "RUN/commands.csv", "--pose-rate", "1e7"], {}, 2, "lower --pose-rate"),
    ("sim --duration 60 --input 3s.csv: an input shorter than --duration is refused naming both",
     ["sim", "--duration", "60", "--input", "RUN/commands.csv", "--out", "TMP/o"], {},
     2, "holds 3 s of commands (t = 0..3 s), less than --duration 60 s"),
    ("--ls-window 500 on a 3 s run is not accepted silently",
     ["estimate", "batch", "RUN", "--method", "ls-ekf", "--ls-window", "500"], {}, 0,
     "tpods: warning: --ls-window 500 s covers all of the run"),
    ("text in steps.csv names the file, line and column",
     ["bench", "fit", "TMP/s", "--order", "2"],
     {"s/raw.csv": "t_s,window,phase,step,n_open,duty_pct,reading_gf,stable\n0,0,zero,-1,0,0,0,1\n",
      "s/steps.csv": "n_open,duty_pct,thrust_gf\n1,10,1.0\n1,50,abc\n1,90,30\n"},
     2, "steps.csv: line 3: column thrust_gf: 'abc' is not a number"),
    ("a NaN step in steps.csv is not dropped silently",
     ["bench", "fit", "TMP/s", "--order", "2"],
     {"s/raw.csv": "t_s,window,phase,step,n_open,duty_pct,reading_gf,stable\n0,0,zero,-1,0,0,0,1\n",
      "s/steps.csv": "n_open,duty_pct,thrust_gf\n1,10,1.0\n1,50,nan\n1,90,30\n1,70,20\n"},
     2, "steps.csv: line 3: column thrust_gf: empty or NaN"),
    ("run plant --mocap udp:127.0.0.1:99999 is refused before the run",
     ["run", "plant", "--mocap", "udp:127.0.0.1:99999", "--duration", "1"], {}, 2,
     "port 99999 is out of range"),
]

# Cases covered elsewhere: (issue text, "path::test").
SEE_ROWS = [
    ("design --out RUN replaced a recorded run's commands.csv",
     "tests/tpods/cli/test_outputs.py::test_existing_folder_is_refused_and_untouched"),
    ("sim --out DIR replaced poses.csv, a stale thrusts.csv stayed",
     "tests/tpods/cli/test_outputs.py::test_sim_force_replaces_the_folder_whole"),
    ("sim interrupted while writing left a mixed run",
     "tests/tpods/cli/test_outputs.py::test_interrupted_sim_leaves_the_old_folder"),
    ("estimate batch/montecarlo --out, bench fit, mocap record replaced earlier results",
     "tests/tpods/cli/test_outputs.py::test_existing_folder_is_refused_and_untouched"),
    ("bench fit --out is a file: an existing table is refused",
     "tests/tpods/cli/test_outputs.py::test_existing_file_is_refused_and_untouched"),
    ("poses in millimetres: converged without a word",
     "tests/tpods/cli/test_estimate_batch.py::test_poses_in_millimetres_warn_on_stderr_naming_the_likely_cause"),
    ("yaw in degrees in batch LS", "tests/estimator/batch/test_least_squares.py::test_yaw_in_degrees_warns_naming_the_cause"),
    ("bifilar trace in degrees", "tests/calibration/test_trace_fit.py::test_yaw_in_degrees_warns"),
    ("all valves closed converged to the initial guess",
     "tests/estimator/batch/test_least_squares.py::test_all_valves_closed_is_not_converged_and_says_why"),
    ("thrust table negative over the duty range (was clipped)",
     "tests/common/test_thrust_table.py::test_negative_thrust_over_the_duty_range_is_refused"),
    ("thrust table without unit taken as gf", "tests/common/test_thrust_table.py::test_a_table_without_unit_is_refused"),
    ("misspelled thrust table keys", "tests/common/test_thrust_table.py::test_misspelled_keys_are_errors_with_the_nearest_key"),
    ("decimal commas in readings", "tests/calibration/test_mass.py::test_decimal_comma_is_refused_clearly"),
    ("BOM in a readings file", "tests/calibration/test_mass.py::test_a_bom_is_accepted"),
    ("calibrate combine ignored mass_sigma",
     "tests/calibration/test_composite.py::test_misspelled_key_is_an_error_naming_the_nearest"),
    ("--spacing 10 without a plausibility warning",
     "tests/tpods/cli/test_calibrate.py::test_bifilar_plausibility_warning_is_one_stderr_line_in_text_mode"),
    ("--out '' wrote into the current folder; outputs at a file / under a file / missing parent",
     "tests/tpods/cli/test_outputs.py::test_impossible_outputs_are_one_line"),
    ("bench emulate --log-dir FILE, run plant --truth-out FILE crashed at the end",
     "tests/tpods/cli/test_outputs.py::test_impossible_outputs_are_one_line"),
    ("option errors prefixed 'tpods <sub>: error:'",
     "tests/tpods/cli/test_main.py::test_option_errors_use_the_documented_prefix"),
    ("--window T0:T1 in estimate, T0,T1 in bifilar; reversed window",
     "tests/tpods/cli/test_calibrate.py::test_bifilar_window_takes_both_syntaxes_and_refuses_a_reversed_one"),
    ("recorders keep partial data marked incomplete, readers warn",
     "tests/tpods/cli/test_partial_runs.py::test_estimate_batch_warns_once_on_a_partial_run"),
    ("a valve controller given as --scale: 'is the load steady?'",
     "tests/bench/test_scale_is_a_balance.py::test_calibrate_mass_with_a_valve_controller_as_scale"),
    ("a gf table labelled N: mass error of 4e13 % without a word",
     "tests/estimator/batch/test_body_warnings.py::test_cli_gf_table_labelled_newtons"),
    ("damaged inputs and odd option values: exit 0/2, no traceback, nothing outside --out changed",
     "tests/tpods/cli/test_properties.py::test_estimate_on_a_damaged_run"),
]

# Cases with a finding and no test yet (they need a device or a network peer); listed so the
# table is complete: see the report of the robustness suite.
OPEN_ROWS: list[tuple[str, str]] = []


def test_a_failed_characterize_does_not_block_a_rerun(tmp_path):
    """A session that fails before its first reading (here: a valve controller that never
    answers) keeps its run.json (status failed, why), and the same --out works again
    without --force, saying what it replaces; a session with readings is still protected."""
    out = tmp_path / "ch"
    argv = ["bench", "characterize", "--valves", "loop://", "--scale", "loop://", "--out", str(out)]
    for i in range(2):
        rc, _, stderr = check(argv, tmp_path, out, "fresh")
        lines = stderr.strip().splitlines()
        assert rc == 2 and "sent nothing" in lines[-1] and "already holds" not in stderr
        assert json.loads((out / "run.json").read_text())["status"] == "failed"
        assert ("replacing" in stderr) == (i == 1)
    (out / "raw.csv").write_text((out / "raw.csv").read_text() + "0.1,0,zero,-1,0,0,0.01,1\n")
    rc, _, stderr = check(argv, tmp_path, out, "existing")
    assert rc == 2 and "already holds" in stderr


@pytest.fixture(scope="module")
def valid_run(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("robust-table") / "run"
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["sim", "--duration", "3", "--seed", "1", "--out", str(d)]) == 0
    return d


def _subst(text: str, run: Path, tmp: Path) -> str:
    return text.replace("RUN", str(run)).replace("TMP", str(tmp))


RUN_ROWS = [pytest.param(*r, id=r[0]) if not hasattr(r, "marks") else
            pytest.param(*r.values, marks=r.marks, id=r.values[0]) for r in RUN_ROWS]


@pytest.mark.parametrize(("case", "argv", "files", "status", "needle"), RUN_ROWS)
def test_issue_case(case, argv, files, status, needle, valid_run, tmp_path):
    work = tmp_path / "work"
    work.mkdir()
    for name, spec in files.items():
        p = work / name
        p.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(spec, tuple):
            _, src, edit = spec
            text = Path(_subst(str(src), valid_run, work)).read_text()
            p.write_text(edit(text) if edit else text)
        else:
            p.write_text(spec)
    args = [_subst(a, valid_run, work) for a in argv]
    out = next((Path(args[i + 1]) for i, a in enumerate(args[:-1]) if a == "--out"), None)
    rc, stdout, stderr = check(args, work, out, "fresh" if out else "none")
    assert rc == status, (case, rc, stderr)
    if status == 2:
        lines = [ln for ln in stderr.splitlines() if ln.strip()]
        assert len(lines) == 1 and needle in lines[0], (case, stderr)
    else:
        assert needle in stdout + stderr, (case, stdout, stderr)


@pytest.mark.parametrize(("case", "where"), SEE_ROWS, ids=[r[0] for r in SEE_ROWS])
def test_issue_case_is_covered_by(case, where):
    path, name = where.split("::")
    text = (ROOT / path).read_text()
    assert re.search(rf"^def {re.escape(name)}\(", text, re.M), f"{case}: {where} is gone"


def test_every_open_case_is_named():
    assert all(note for _, note in OPEN_ROWS)  # none left open
    assert run_cli  # the harness is shared with the property suite
