"""The run-folder writer: CSV logs (exact bytes, flush per row), atomic JSON, one JSON policy."""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path

import numpy as np
import pytest

import common
from common import runwriter
from common.runfolder import read_run, write_run
from common.runwriter import (
    CommandLog,
    CsvLog,
    dumps_json,
    json_default,
    run_header,
    write_json_atomic,
)


def test_csv_log_writes_exact_bytes_in_each_columns_format(tmp_path):
    p = tmp_path / "poses.csv"
    log = CsvLog(p, ("t", "x", "y", "psi"), ("%.9f", "%.12g", "%.12g", "%.12g"))
    assert p.read_bytes() == b"t,x,y,psi\n"                       # header at once
    log.write(0.5, 1 / 3, -2.0e-7, np.float64(3.0))
    log.write(np.float64(1.25), 1e20, 0.0, -0.0)
    log.close()
    log.close()                                                  # again: nothing
    assert p.read_bytes() == (b"t,x,y,psi\n"
                              b"0.500000000,0.333333333333,-2e-07,3\n"
                              b"1.250000000,1e+20,0,-0\n")
    assert log.n_rows == 2 and log.closed


def test_csv_log_text_and_callable_cells_are_quoted_as_csv_quotes_them(tmp_path):
    p = tmp_path / "samples.csv"
    with CsvLog(p, ("body", "n", "v", "ok"), (str, "%d", repr, lambda b: "true" if b else "false")) as log:
        log.write("m/1", 3, 0.1, True)
        log.write("a,b", 4, 1e-05, False)
        log.write('q"x', 5, -2.5, True)
    assert p.read_text() == ('body,n,v,ok\n'
                             'm/1,3,0.1,true\n'
                             '"a,b",4,1e-05,false\n'
                             '"q""x",5,-2.5,true\n')


def test_csv_log_flushes_every_row_so_a_reader_sees_it_before_close(tmp_path):
    p = tmp_path / "raw.csv"
    log = CsvLog(p, ("t", "v"), "%g")
    for i in range(3):
        log.write(i, 2 * i)
        assert p.read_text().splitlines()[-1] == f"{i},{2 * i}"   # on disk while open
    log.close()


def test_csv_log_flush_policies(tmp_path):
    lazy = CsvLog(tmp_path / "lazy.csv", ("t",), "%g", flush_every_s=None)
    lazy.write(1.0)
    assert (tmp_path / "lazy.csv").read_text() == "t\n"           # only the header so far
    lazy.close()
    assert (tmp_path / "lazy.csv").read_text() == "t\n1\n"
    timed = CsvLog(tmp_path / "timed.csv", ("t",), "%g", flush_every_s=3600.0)
    timed.write(1.0)
    assert (tmp_path / "timed.csv").read_text() == "t\n"
    timed.flush()
    assert (tmp_path / "timed.csv").read_text() == "t\n1\n"
    timed.close()


def test_csv_log_write_many_matches_np_savetxt(tmp_path):
    rng = np.random.default_rng(1)
    data = rng.normal(size=(40, 4)) * np.array([1e-9, 1.0, 1e7, 123.456])
    data[0] = [-0.0, 0.0, 1e-320, 1 / 3]
    with CsvLog(tmp_path / "a.csv", ("t", "x", "y", "psi"), "%.12g", flush_every_s=None) as log:
        log.write_many(data)
    np.savetxt(tmp_path / "b.csv", data, delimiter=",", header="t,x,y,psi", comments="", fmt="%.12g")
    assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "b.csv").read_bytes()


def test_csv_log_refuses_a_row_of_the_wrong_width(tmp_path):
    with pytest.raises(ValueError, match="2 formats for 3 columns"):
        CsvLog(tmp_path / "x.csv", ("a", "b", "c"), ("%g", "%g"))
    with CsvLog(tmp_path / "y.csv", ("a", "b"), "%g") as log, pytest.raises(ValueError, match="3 values"):
        log.write(1, 2, 3)


def test_command_log_exact_bytes_and_increasing_time(tmp_path):
    p = tmp_path / "commands.csv"
    log = CommandLog(p, 4)
    assert log.add(0.0001234567891, [50, np.float64(64.14213562), 0, 12.5])
    assert not log.add(0.0001234567891, [1, 2, 3, 4])            # not after the previous row
    assert log.add(2.5, (0.0, 0.0, 0.0, 0.0))
    log.close()
    assert p.read_bytes() == (b"t,d1,d2,d3,d4\n"
                              b"0.000123456789,50,64.1421,0,12.5\n"
                              b"2.5,0,0,0,0\n")
    assert log.rows == 2 and log.last_t == 2.5 and log.last_duty == (0.0, 0.0, 0.0, 0.0)
    with CommandLog(tmp_path / "live.csv", 2, t_format="%.9f") as live:   # the live recorder's time format
        live.add(0.25, (10, 90))
    assert (tmp_path / "live.csv").read_text() == "t,d1,d2\n0.250000000,10,90\n"


def test_player_command_log_is_the_common_one():
    from tpods.player import CommandLog as PlayerLog

    assert PlayerLog is CommandLog


def test_json_policy_numpy_path_nan():
    data = {"f32": np.float32(0.25), "i64": np.int64(3), "b": np.bool_(True), "arr": np.arange(3),
            "m": np.eye(2), "p": Path("/runs/a"), "nan": float("nan"), "inf": -math.inf,
            "np_nan": np.float64("nan"), "t": (1, 2), "obj": object.__new__(_Named)}
    text = dumps_json(data)
    assert text.endswith("}\n")
    back = json.loads(text)
    assert back["f32"] == 0.25 and back["i64"] == 3 and back["b"] is True
    assert back["arr"] == [0, 1, 2] and back["m"] == [[1.0, 0.0], [0.0, 1.0]]
    assert back["p"] == "/runs/a" and back["t"] == [1, 2] and back["obj"] == "named"
    assert math.isnan(back["nan"]) and back["inf"] == -math.inf and math.isnan(back["np_nan"])
    # NaN and infinities: Python's literals, as every recorder wrote them
    assert '"nan": NaN' in text and '"inf": -Infinity' in text and '"np_nan": NaN' in text
    assert json_default(np.float32(1.5)) == 1.5 and type(json_default(np.int32(2))) is int


class _Named:
    def __str__(self) -> str:
        return "named"


def test_write_json_atomic_exact_bytes(tmp_path):
    p = write_json_atomic(tmp_path / "run.json", {"kind": "x", "n": np.int64(2), "v": [0.5, None]})
    assert p.read_bytes() == b'{\n  "kind": "x",\n  "n": 2,\n  "v": [\n    0.5,\n    null\n  ]\n}\n'
    assert sorted(x.name for x in tmp_path.iterdir()) == ["run.json"]    # no .tmp left behind


@pytest.mark.parametrize("fail_at", ["fsync", "replace"])
def test_interrupted_atomic_write_leaves_the_old_file_intact(tmp_path, monkeypatch, fail_at):
    p = tmp_path / "run.json"
    write_json_atomic(p, {"status": "running"})
    old = p.read_bytes()

    def boom(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(runwriter.os, fail_at, boom)
    with pytest.raises(KeyboardInterrupt):
        write_json_atomic(p, {"status": "success", "big": list(range(10000))})
    monkeypatch.undo()
    assert p.read_bytes() == old
    assert not (tmp_path / "run.json.tmp").exists()


def test_a_crash_between_write_and_rename_leaves_the_old_file_and_a_tmp(tmp_path, monkeypatch):
    """kill -9 after the temporary file is written: the old file is what readers see."""
    p = tmp_path / "run.json"
    write_json_atomic(p, {"status": "running"})
    old = p.read_bytes()
    real_replace = os.replace

    def killed(src, dst):
        raise SystemExit(137)           # stands for the process dying before the rename

    monkeypatch.setattr(runwriter.os, "replace", killed)
    with pytest.raises(SystemExit):
        write_json_atomic(p, {"status": "success"})
    assert p.read_bytes() == old and json.loads(old) == {"status": "running"}
    monkeypatch.setattr(runwriter.os, "replace", real_replace)
    write_json_atomic(p, {"status": "success"})                   # the next write replaces it
    assert json.loads(p.read_text()) == {"status": "success"}


def test_unserialisable_data_never_touches_the_file(tmp_path):
    p = tmp_path / "run.json"
    write_json_atomic(p, {"a": 1})
    circular: dict = {}
    circular["self"] = circular
    with pytest.raises(ValueError):
        write_json_atomic(p, circular)
    assert json.loads(p.read_text()) == {"a": 1}
    assert not (tmp_path / "run.json.tmp").exists()


def test_run_header_keys_and_order():
    h = run_header("input-play", status="running", body="tpods1")
    assert list(h) == ["kind", "software", "created", "status", "body"]
    assert h["kind"] == "input-play" and h["software"] == f"tpods {common.__version__}"
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\+00:00", h["created"])
    assert run_header("x", created=0.0)["created"] == "1970-01-01T00:00:00+00:00"


def test_run_json_written_through_the_writer_exact_bytes(tmp_path):
    meta = run_header("sim", created=1.7e9, settings={"seed": np.int64(1)}, path=Path("runs/a"))
    write_json_atomic(tmp_path / "run.json", meta)
    assert (tmp_path / "run.json").read_text() == (
        '{\n  "kind": "sim",\n  "software": "tpods ' + common.__version__ + '",\n'
        '  "created": "2023-11-14T22:13:20+00:00",\n'
        '  "settings": {\n    "seed": 1\n  },\n  "path": "runs/a"\n}\n')


def test_write_run_goes_through_the_writer_and_reads_back(tmp_path):
    t = np.array([0.0, 0.1, 0.2])
    write_run(tmp_path / "r", cmd_t=t, duty_pct=np.full((3, 4), 50.0), pose_t=t,
              pose=np.array([[0.0, 0.0, 0.0], [1 / 3, 2e-7, -1.0], [1.0, 1.0, 3.0]]),
              meta={"kind": "sim", "n": np.int64(3), "nan": math.nan})
    assert (tmp_path / "r" / "poses.csv").read_bytes() == (
        b"t,x,y,psi\n0,0,0,0\n0.1,0.333333333333,2e-07,-1\n0.2,1,1,3\n")
    assert (tmp_path / "r" / "commands.csv").read_text().splitlines()[1] == "0,50,50,50,50"
    run = read_run(tmp_path / "r")
    assert run.meta["n"] == 3 and math.isnan(run.meta["nan"])
    assert sorted(x.name for x in (tmp_path / "r").iterdir()) == [
        "commands.csv", "poses.csv", "run.json"]
