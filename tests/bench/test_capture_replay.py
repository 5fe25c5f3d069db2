"""Serial capture and replay (issue 19): transcripts of both devices of a characterisation
session against the emulators, replayed strictly (and paced) through the real drivers."""

import json
import math

import numpy as np
import pytest
import serial

import bench.serial_link  # noqa: F401  registers replay://
from bench.capture import FORMAT, read_transcript
from bench.fit import fit_steps
from bench.ohaus.driver import OhausScout
from bench.serial_link import SerialLink
from bench.session import SessionConfig, run_session
from bench.valves import ValveController
from common.errors import DeviceError
from tests.support.bench import Bench

CFG = SessionConfig(nozzles=(1, 2), duties_pct=(40, 70, 90), dwell_s=0.3, settle_s=0.1,
                    zero_settle_s=0.1, zero_dwell_s=0.1, watchdog_ms=300)
EXACT = ["step", "n_open", "duty_pct", "n", "n_unstable", "mean_raw_gf", "zero_before_gf",
         "zero_after_gf", "drift_gf", "thrust_gf", "std_gf", "sem_gf"]


def _capture(tmp_path, seed=5):
    rec = tmp_path / "rec"
    b = Bench(seed=seed)
    try:
        v, s = b.paths
        with ValveController(v, capture=rec / "valves.serial.jsonl") as valves, \
                OhausScout(s, capture=rec / "scale.serial.jsonl") as scale:
            live = run_session(valves, scale, CFG, tmp_path / "live", progress=False)
    finally:
        b.stop()
    assert live.status == "success"
    return rec, live


def _replay(rec, out, cfg=CFG, **kw):
    with ValveController(f"replay://{rec}/valves.serial.jsonl", **kw) as valves, \
            OhausScout(f"replay://{rec}/scale.serial.jsonl") as scale:
        res = run_session(valves, scale, cfg, out, progress=False)
        return res, valves._link.port, scale._link.port


def _same(a, b) -> bool:
    return len(a) == len(b) and np.allclose(a[EXACT].to_numpy(float), b[EXACT].to_numpy(float),
                                            rtol=0, atol=1e-12, equal_nan=True)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """A captured session whose strict replay is exact (a reading within microseconds of a
    window edge can fall on the other side on replay: then it is recorded again; measured:
    about 1 capture in 6 with these 100 Hz prints on an idle machine; in one loaded CI run
    4 captures in a row missed it, each by one reading 0.1-0.3 ms from a window edge: so
    up to 8 tries)."""
    for attempt in range(8):
        tmp = tmp_path_factory.mktemp(f"capture{attempt}")
        rec, live = _capture(tmp, seed=5 + attempt)
        res, _, _ = _replay(rec, tmp / "replay")
        if _same(live.steps, res.steps):
            return rec, live, attempt
    pytest.fail("no capture in 8 replayed exactly")


def test_transcripts_are_documented_json_lines(recorded):
    rec, live, _ = recorded
    for name, device in (("valves", "valve controller"), ("scale", "OHAUS balance")):
        lines = (rec / f"{name}.serial.jsonl").read_text().splitlines()
        header = json.loads(lines[0])
        assert header["format"] == FORMAT and header["device"] == device
        assert header["url"].startswith("/dev/") and "baudrate" in header["settings"]
        objs = [json.loads(x) for x in lines[1:]]
        assert {o["dir"] for o in objs} == {"tx", "rx"}
        t = [o["t"] for o in objs]
        assert t == sorted(t) or name == "valves"   # the watchdog feeder writes from its thread
        for o in objs:
            assert bytes.fromhex(o["hex"]).decode("latin-1") == o["ascii"]
    v = (rec / "valves.serial.jsonl").read_text()
    assert '"ascii":"ID?\\n"' in v and json.loads(v.splitlines()[0])["keepalive"] == "PING\n"
    header, events = read_transcript(rec / "scale.serial.jsonl")
    assert any(d == "tx" and data == b"CP\r\n" for _, d, data, _, _ in events)


def test_strict_replay_gives_the_same_steps_and_thrust_table(recorded, tmp_path):
    """Done-when (issue 19): a recorded session replays strictly through today's drivers
    and gives the same thrust table to 1e-12."""
    rec, live, _ = recorded
    res, vport, sport = _replay(rec, tmp_path / "replay")
    assert res.status == "success" and res.n_readings == live.n_readings
    assert _same(live.steps, res.steps)
    # times: t = 0 is the host's clock when run_session starts, not a recorded event
    assert np.allclose(live.steps["t_start_s"], res.steps["t_start_s"], atol=0.01)
    a = fit_steps(live.steps, order=1).table()
    b = fit_steps(res.steps, order=1).table()
    for k in a.coefficients:
        assert np.allclose(a.coefficients[k], b.coefficients[k], rtol=0, atol=1e-12), k
    assert vport.mismatch is None and sport.mismatch is None
    assert sport.remaining == 0 and vport.remaining <= 2     # the host read the whole recording
    assert json.loads((tmp_path / "replay" / "run.json").read_text())["valves_closed_confirmed"] is True


def test_replay_is_deterministic(recorded, tmp_path):
    rec, _, _ = recorded
    a, _, _ = _replay(rec, tmp_path / "a")
    b, _, _ = _replay(rec, tmp_path / "b")
    assert _same(a.steps, b.steps)
    assert np.array_equal(a.steps[["t_start_s", "t_end_s"]].to_numpy(), b.steps[["t_start_s", "t_end_s"]].to_numpy())


def test_a_changed_command_fails_naming_the_first_differing_exchange(recorded, tmp_path):
    rec, _, _ = recorded
    cfg = SessionConfig(**{**CFG.__dict__, "duties_pct": (40, 75, 90)})   # the host now sends 75 %
    with pytest.raises(DeviceError) as e:
        _replay(rec, tmp_path / "x", cfg)
    msg = str(e.value)
    print(msg)
    assert "strict replay of valves.serial.jsonl (valve controller): exchange" in msg
    assert "the recording has b'DUTY* 70 0 0 0\\n', the host sent b'DUTY* 75 0 0 0\\n'" in msg
    assert "recorded at t=" in msg
    run = json.loads((tmp_path / "x" / "run.json").read_text())
    assert run["status"] == "failed"


def test_a_changed_byte_in_the_file_fails_readably(recorded, tmp_path):
    rec, _, _ = recorded
    edited = tmp_path / "edited"
    edited.mkdir()
    (edited / "scale.serial.jsonl").write_text((rec / "scale.serial.jsonl").read_text())
    lines = (rec / "valves.serial.jsonl").read_text().splitlines()
    # one tx byte: the recording says FREQ 11 where the host sends FREQ 10
    i = next(i for i, x in enumerate(lines) if '"ascii":"FREQ 10\\n"' in x)
    lines[i] = lines[i].replace("46524551203130", "46524551203131").replace("FREQ 10", "FREQ 11")
    (edited / "valves.serial.jsonl").write_text("\n".join(lines) + "\n")
    with pytest.raises(DeviceError, match=r"the recording has b'FREQ 11\\n', the host sent b'FREQ 10\\n'"):
        _replay(edited, tmp_path / "x")
    # one rx byte: the controller's identity
    lines = (rec / "valves.serial.jsonl").read_text().splitlines()
    j = next(i for i, x in enumerate(lines) if "VALVES" in x)
    lines[j] = lines[j].replace(b"VALVES".hex(), b"VALVEZ".hex())
    (edited / "valves.serial.jsonl").write_text("\n".join(lines) + "\n")
    with pytest.raises(DeviceError, match="not a TPODS valve controller: ID. answered 'TPODS-VALVEZ"):
        _replay(edited, tmp_path / "y")


def test_paced_replay_tolerates_another_poll_timing_and_other_commands(recorded):
    rec, _, _ = recorded
    _, events = read_transcript(rec / "scale.serial.jsonl")
    expected = b"".join(data for _, d, data, _, _ in events if d == "rx")
    link = SerialLink(f"replay://{rec}/scale.serial.jsonl?mode=paced", "OHAUS balance", poll_s=0.003)
    try:
        link.write(b"XX\r\n")                              # not what was recorded: accepted
        got = []
        while (line := link.readline(link.line_t + 0.5 if got else 10**9)) is not None:
            got.append(line)
    finally:
        link.close()
    want = [x for x in expected.replace(b"\r\n", b"\n").split(b"\n") if x.strip()]
    assert got == want
    assert link.port.tx_bytes == 4


def test_paced_replay_answers_at_the_recorded_time(tmp_path):
    p = tmp_path / "t.serial.jsonl"
    p.write_text(json.dumps({"format": FORMAT, "device": "x", "url": "u", "settings": {},
                             "t_open_monotonic": 0.0}) + "\n"
                 + '{"t":0.15,"dir":"rx","hex":"41","ascii":"A"}\n')
    port = serial.serial_for_url(f"replay://{p}?mode=paced", timeout=0.05)
    assert port.read(1) == b""                                 # times out like a port
    port.timeout = 1.0
    assert port.read(1) == b"A"
    port.timeout = 0
    assert port.read(1) == b""                                 # the recording is over
    port.close()


def test_strict_read_timeouts_behave_like_a_port(tmp_path):
    p = tmp_path / "t.serial.jsonl"
    p.write_text(json.dumps({"format": FORMAT, "device": "x", "url": "u", "settings": {},
                             "t_open_monotonic": 100.0}) + "\n"
                 + '{"t":0.01,"dir":"tx","hex":"3f0a","ascii":"?\\n"}\n'
                 + '{"t":0.5,"dir":"rx","hex":"4f4b0a","ascii":"OK\\n","t_call":0.011}\n')
    from bench import clock
    port = serial.serial_for_url(f"replay://{p}", timeout=0.2)
    try:
        assert clock.monotonic() == 100.0                       # the recording's time line
        assert port.read(3) == b""                              # nothing before the command
        assert clock.monotonic() == pytest.approx(100.2)
        port.write(b"?\n")
        assert port.read(3) == b"OK\n"
        assert clock.monotonic() == 100.5
        with pytest.raises(serial.SerialException, match="the recording ends after exchange 1; the host sent b'more"):
            port.write(b"more\n")
    finally:
        port.close()
    assert not math.isclose(clock.monotonic(), 100.5)          # system clock again


def test_bad_urls_and_files_are_one_line(tmp_path):
    with pytest.raises(DeviceError, match="no such serial transcript"):
        SerialLink(f"replay://{tmp_path}/none.jsonl", "valve controller")
    with pytest.raises(DeviceError, match="mode must be strict or paced"):
        SerialLink(f"replay://{tmp_path}/x.jsonl?mode=fast", "valve controller")
