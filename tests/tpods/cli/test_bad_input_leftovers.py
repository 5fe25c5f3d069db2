"""Issue 26: the leftovers of the new-user probe of bad inputs, one test each (the rules are
``common.plausible``'s; tests/common/test_plausible.py checks them alone).

Tracebacks (an absurd Monte Carlo duration, ``bench fit --plot-dir`` naming a file), unclear
messages (a duty error without file and line, an absurd pose, a reversed duty range) and
silently wrong results (an empty pan, a 326 kg module, grams typed as kg in a parts file,
``mocap record --t0 nan``, 315 % efficiencies, an uncertainty entry for a missing nozzle count,
overlapping modules, a cut MCAP as a fixture, live commands that received nothing).
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import re
import shutil
import socket
from pathlib import Path

import pytest

from tests.support.cli import run_in_process
from tests.support.net import free_port
from tests.tpods.cli.test_outputs import write_session
from tpods.cli import main
from tpods.fixtures import FIXTURES_ROOT

TABLE_WITHOUT_ROW_2 = ('unit = "gf"\nduty_range = [10, 90]\n[nozzles.1]\ncoefficients = [0.0, 1.0]\n'
                       '[uncertainty]\nscale_rel = 0.01\n[uncertainty.nozzles.2]\nscale_rel = 0.05\n')
OVERLAPPING = ('name = "dup"\n[[modules]]\nname = "a"\nposition_m = [0.2, 0.0]\n[[modules]]\n'
               'name = "b"\nposition_m = [0.2, 0.0]\n')


def tpods(argv: list[str]) -> tuple[int, str, str]:
    """(status, stdout, stderr) of ``tpods argv`` run in-process."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            rc = main(list(argv))
        except SystemExit as exc:
            rc = exc.code
    return rc, out.getvalue(), err.getvalue()


def error_line(rc: int, err: str) -> str:
    """The one ``tpods: error:`` line of a refusal."""
    assert rc == 2, err
    assert "Traceback" not in err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert lines and lines[-1].startswith("tpods: error: "), err
    return lines[-1]


@pytest.fixture(scope="module")
def sim_run(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("leftovers") / "run"
    assert tpods(["sim", "--duration", "4", "--seed", "1", "--out", str(d)])[0] == 0
    return d


def edited_copy(src: Path, dest: Path, name: str, row: int, col: int, value: str) -> Path:
    """A copy of run folder ``src`` with one cell of ``name`` (data row ``row``) replaced."""
    shutil.copytree(src, dest)
    rows = list(csv.reader((dest / name).open()))
    rows[row][col] = value
    with (dest / name).open("w", newline="") as f:
        csv.writer(f).writerows(rows)
    return dest


# ------------------------------------------------------------------------- tracebacks


def test_montecarlo_refuses_an_absurd_duration_before_allocating():
    line = error_line(*tpods(["estimate", "montecarlo", "--duration", "1e12", "--runs", "2"])[::2])
    assert "--duration 1e12 s" in line and "1.2e14 poses" in line
    assert "memory; this machine has" in line and "lower --duration" in line


def test_structure_montecarlo_refuses_an_absurd_duration_too(tmp_path):
    s = FIXTURES_ROOT / "structure-run" / "structure.toml"
    line = error_line(*tpods(["estimate", "montecarlo", "--structure", str(s), "--duration",
                              "1e9", "--runs", "2"])[::2])
    assert "--duration 1e9 s" in line and "memory" in line


def test_bench_fit_plot_dir_naming_a_file_is_refused_before_any_work(tmp_path):
    session = write_session(tmp_path / "session")
    (tmp_path / "plots.txt").write_text("a file\n")
    for plot_dir in (tmp_path / "plots.txt", tmp_path / "plots.txt" / "sub"):
        rc, _, err = tpods(["bench", "fit", str(session), "--plot-dir", str(plot_dir), "--order", "2"])
        line = error_line(rc, err)
        assert "--plot-dir" in line and "plots.txt" in line and "is a file" in line
        assert not (session / "thrust_table.toml").exists()  # no table written


# ------------------------------------------------------------------------- unclear messages


def test_montecarlo_input_duty_error_names_file_and_line(sim_run, tmp_path):
    bad = edited_copy(sim_run, tmp_path / "bad", "commands.csv", 5, 2, "150") / "commands.csv"
    line = error_line(*tpods(["estimate", "montecarlo", "--input", str(bad), "--duration", "3",
                              "--runs", "2"])[::2])
    assert line.endswith(f"{bad}: line 6: duty outside 0..100 %")
    # an open duty outside the table's valid range, by line too
    bad2 = edited_copy(sim_run, tmp_path / "bad2", "commands.csv", 7, 3, "95") / "commands.csv"
    line = error_line(*tpods(["estimate", "montecarlo", "--input", str(bad2), "--duration", "3",
                              "--runs", "2"])[::2])
    assert f"{bad2}: line 8: duty d3 = 95 %" in line and "valid range 10-90 %" in line


def test_an_absurd_pose_is_refused_naming_file_and_line(sim_run, tmp_path):
    bad = edited_copy(sim_run, tmp_path / "bad", "poses.csv", 50, 1, "1e30")
    for argv in (["estimate", "batch", str(bad)], ["estimate", "batch", str(bad), "--method", "ekf"]):
        line = error_line(*tpods(argv)[::2])
        assert f"{bad / 'poses.csv'}: line 51: x = 1e+30 m is not a position on an air table" in line


@pytest.mark.parametrize("argv, fix", [
    (["bench", "characterize", "--valves", "x", "--scale", "y", "--duty", "90:10:10"], "give 10:90:10"),
    (["bench", "characterize", "--valves", "x", "--scale", "y", "--duty-limits", "90,10"], "give 10,90"),
    (["run", "play", "--valves", "x", "--duty-limits", "90,10"], "give --duty-limits 10,90"),
])
def test_a_reversed_duty_range_is_called_reversed(tmp_path, argv, fix):
    out = ["--out", str(tmp_path / "o")] if argv[0] == "bench" else []
    line = error_line(*tpods(argv + out)[::2])
    assert "90..10 % is reversed" in line and fix in line
    assert not (tmp_path / "o").exists()


def test_a_table_with_a_reversed_duty_range_is_called_reversed(tmp_path):
    t = tmp_path / "t.toml"
    t.write_text('unit = "gf"\nduty_range = [90, 10]\n[nozzles.1]\ncoefficients = [0.0, 1.0]\n')
    line = error_line(*tpods(["sim", "--thrust-table", str(t), "--out", str(tmp_path / "o")])[::2])
    assert "reversed" in line and "duty_range = [10, 90]" in line


# ------------------------------------------------------------------------- silently wrong


def test_calibrate_mass_refuses_an_empty_pan():
    line = error_line(*tpods(["calibrate", "mass", "--values", "0.4,1.1,0.8"])[::2])
    assert "within the balance's accuracy +-2.5 g of zero" in line and "pan empty" in line


def test_calibrate_mass_warns_of_a_326_kg_module():
    rc, out, err = tpods(["calibrate", "mass", "--values", "720.1,720.3", "--unit", "lb", "--json"])
    assert rc == 0
    assert "tpods: warning: mass 327 kg is outside 0.05-200 kg" in err and "'lb'" in err
    assert json.loads(out)["warnings"]
    rc, out, err = tpods(["calibrate", "mass", "--values", "720.1,720.3"])  # grams: no word
    assert rc == 0 and "warning" not in err


def test_calibrate_combine_warns_of_grams_typed_as_kg(tmp_path):
    ex = Path(__file__).resolve().parents[3] / "calibration" / "examples" / "truss_two_modules.toml"
    f = tmp_path / "parts.toml"
    f.write_text(ex.read_text().replace("mass_kg = 0.720", "mass_kg = 720"))
    rc, _, err = tpods(["calibrate", "combine", str(f)])
    assert rc == 0
    assert "tpods: warning: part 'module A': mass 720 kg is above 200 kg" in err
    assert "mass_kg typed in grams?" in err and "the composite: mass" in err
    rc, _, err = tpods(["calibrate", "combine", str(ex)])
    assert rc == 0 and "warning" not in err


def test_mocap_record_refuses_a_nan_t0(tmp_path):
    for t0, out in (("nan", tmp_path / "rec"), ("inf", tmp_path / "rec.mcap")):
        line = error_line(*tpods(["mocap", "record", "--t0", t0, "--out", str(out),
                                  "--duration", "1"])[::2])
        assert f"--t0 must be a finite time in seconds, got {t0}" in line
        assert not out.exists()


def test_the_recorder_writes_no_nan_time(tmp_path):
    from common.errors import UserError
    from common.wire import encode_pose
    from mocap_bridge.recorder import Recorder

    with pytest.raises(UserError, match="finite"):
        Recorder(tmp_path / "r", t0=float("nan"))
    rec = Recorder(tmp_path / "r2", t0=float("-1e308"))
    rec.handle(encode_pose("m", 1, 1e308, 1e308, (0.1, 0.2, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0)))
    rec.close()
    assert rec.counters["recorded"] == 0 and rec.counters["malformed"] == 1
    assert "nan" not in (tmp_path / "r2" / "m" / "poses.csv").read_text()


def test_calibrate_thrust_on_the_wrong_body_warns(tmp_path):
    run_dir = tmp_path / "light"
    assert tpods(["sim", "--input", "translate-rotate", "--duration", "28", "--mass", "0.72",
                  "--izz", "1.2e-3", "--seed", "2", "--out", str(run_dir)])[0] == 0
    rc, _, err = tpods(["calibrate", "thrust", str(run_dir), "--mass", "2.268", "--izz", "3.78e-3",
                        "--mass-sigma", "0.001", "--izz-sigma", "1e-5", "--thrust-table", "table2",
                        "--out", str(tmp_path / "cal.toml")])
    assert rc == 0, err
    assert re.search(r"tpods: warning: efficiency.1 = 31[0-9] %", err) and "outside 50-150 %" in err
    # the known body itself implausible (grams typed as kg): said before the fit
    rc, _, err = tpods(["calibrate", "thrust", str(run_dir), "--mass", "720", "--izz", "1.2e-3",
                        "--thrust-table", "table2", "--out", str(tmp_path / "cal2.toml")])
    assert "tpods: warning: the known body (--mass, --izz): mass 720 kg is outside" in err


def test_an_uncertainty_entry_for_a_missing_nozzle_count_is_refused(tmp_path):
    t = tmp_path / "t.toml"
    t.write_text(TABLE_WITHOUT_ROW_2)
    line = error_line(*tpods(["sim", "--thrust-table", str(t), "--out", str(tmp_path / "o")])[::2])
    assert f"{t}: [uncertainty.nozzles.2]: the table has no [nozzles.2] row" in line


@pytest.mark.parametrize("cmd", [["sim", "--duration", "2"], ["design", "--duration", "5"]])
def test_overlapping_modules_are_refused(tmp_path, cmd):
    s = tmp_path / "s.toml"
    s.write_text(OVERLAPPING)
    line = error_line(*tpods(cmd + ["--structure", str(s), "--out", str(tmp_path / "o")])[::2])
    assert f"{s}: modules 'a' and 'b' are 0 cm apart" in line and "overlap" in line
    assert not (tmp_path / "o").exists()


def test_fixture_add_refuses_a_cut_mcap_and_a_partial_run(tmp_path, sim_run):
    full = FIXTURES_ROOT / "live-run" / "recording.mcap"
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(full.read_bytes()[: full.stat().st_size * 2 // 3])
    line = error_line(*tpods(["fixture", "add", str(cut), "--name", "f", "--root",
                              str(tmp_path / "fx")])[::2])
    assert f"{cut}: the recording is cut" in line
    partial = tmp_path / "partial"
    shutil.copytree(sim_run, partial)
    meta = json.loads((partial / "run.json").read_text())
    (partial / "run.json").write_text(json.dumps({**meta, "status": "running"}))
    line = error_line(*tpods(["fixture", "add", str(partial), "--name", "g", "--root",
                              str(tmp_path / "fx")])[::2])
    assert "is a partial run" in line and "'running'" in line
    assert not (tmp_path / "fx" / "f").exists() and not (tmp_path / "fx" / "g").exists()


def _no_network(tmp_path) -> list[str]:
    return ["--listen", f"tcp/127.0.0.1:{free_port()}", "--no-multicast"]


def test_estimate_live_that_received_nothing_fails(tpods_exe, tmp_path):
    r = run_in_process("estimate", "live", "--duration", "1.5", "--quiet", "--out",
                       str(tmp_path / "live"), *_no_network(tmp_path))
    line = error_line(r.returncode, r.stderr)
    assert "no estimate: received no poses on tpods/mocap/tpods1/pose" in line
    assert json.loads((tmp_path / "live" / "run.json").read_text())["status"] == "failed"


def test_mocap_bridge_that_published_nothing_fails(tpods_exe, tmp_path):
    port = free_port(socket.SOCK_DGRAM)
    r = run_in_process("mocap", "bridge", "--source", f"vicon-udp:{port}", "--bind", "127.0.0.1",
                       "--duration", "1.5", "--quiet", *_no_network(tmp_path))
    line = error_line(r.returncode, r.stderr)
    assert f"the bridge published no poses: no datagram arrived on UDP port {port}" in line
    assert "published 0 poses" in r.stdout


def test_mocap_record_that_received_nothing_fails(tpods_exe, tmp_path):
    r = run_in_process("mocap", "record", "--out", str(tmp_path / "rec"), "--duration", "1.5",
                       "--quiet", *_no_network(tmp_path))
    line = error_line(r.returncode, r.stderr)
    assert "received nothing on tpods/mocap/**" in line
    assert json.loads((tmp_path / "rec" / "recording.json").read_text())["status"] == "failed"
