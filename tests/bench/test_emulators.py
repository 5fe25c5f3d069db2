"""The emulators in-process (exact, with an injected clock) and behind ptys with the real drivers."""

import math
import time

import pytest

from bench.emulators import EmulatedScout, EmulatedValveController, serve_pty
from bench.ohaus.driver import OhausScout, parse_weight_line
from bench.valves import ValveController
from common.errors import DeviceError
from common.thrust_table import ThrustTable


class Clock:
    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


def quiet_scout(valves=None, clock=None, **kw):
    opts = dict(noise_g=0.0, drift_g_per_s=0.0, unstable_prob=0.0, garbage_prob=0.0, lag_s=0.0)
    opts.update(kw)
    return EmulatedScout(valves, clock=clock or Clock(), **opts)


def test_valve_emulator_protocol_and_log():
    clk = Clock()
    ev = EmulatedValveController(4, clock=clk)
    seen = []
    ev.add_listener(lambda t, d: seen.append((t, d)))
    assert ev.process_line("ID?") == "TPODS-VALVES 1.0-emu 4"
    assert ev.process_line("DUTY* 10 20 30 40.5") == "OK"
    assert ev.process_line("STATE?") == "STATE 10 20 30 40.5"
    assert ev.process_line("DUTY 5 10").startswith("ERR")
    assert ev.process_line("DUTY 1 101").startswith("ERR")
    assert ev.process_line("FREQ 0").startswith("ERR")
    assert ev.process_line("BOGUS").startswith("ERR")
    assert ev.process_line("DUTY 1 x").startswith("ERR")
    clk.t += 1
    assert ev.process_line("OFF") == "OK"
    assert ev.duties == (0, 0, 0, 0)
    assert [c.duties for c in ev.log] == [(0,) * 4, (10, 20, 30, 40.5), (0,) * 4]
    assert seen == [(100.0, (10, 20, 30, 40.5)), (101.0, (0.0,) * 4)]
    assert ev.closed_since() == 101.0


def test_valve_emulator_watchdog_closes_at_expiry():
    clk = Clock()
    ev = EmulatedValveController(2, clock=clk)
    ev.process_line("WDT 200")
    ev.process_line("DUTY 1 50")
    clk.t += 0.15
    ev.process_line("PING")                # fed
    clk.t += 0.15
    out, nxt = ev.tick(clk.t)
    assert ev.duties == (50, 0) and nxt == pytest.approx(clk.t + 0.05 + 1e-4)
    clk.t += 0.3
    ev.tick(clk.t)
    assert ev.duties == (0, 0) and ev.watchdog_trips == 1
    assert ev.log[-1].cause == "watchdog" and ev.log[-1].t == pytest.approx(100.35)  # last command + 200 ms


def test_scout_emulator_truth_lag_and_commands():
    clk = Clock()
    ev = EmulatedValveController(4, clock=clk)
    es = quiet_scout(ev, clk, lag_s=0.3, load_g=100.0)
    table = ThrustTable.default()
    assert es.command("IP") == b"    100.00 g\r\n"
    ev.process_line("DUTY* 50 50 0 0")     # two open: Table 2 row 2 at 50 %
    truth = float(table.per_nozzle(50, 2))
    assert es.truth_thrust_gf() == pytest.approx(truth)
    clk.t += 0.3                           # one time constant
    assert es.gross_g() == pytest.approx(100 + truth * (1 - math.exp(-1)))
    line = es.command("IP")
    assert line.endswith(b" g ?\r\n")      # still settling: unstable
    assert es.command("SP") == b""         # SP waits for a stable reading
    clk.t += 5.0
    out, _ = es.tick(clk.t)
    assert parse_weight_line(out).value == pytest.approx(100 + truth, abs=0.006)
    assert es.command("Z") == b"OK!\r\n"
    assert es.command("IP") == b"      0.00 g\r\n"
    ev.process_line("DUTY 1 0")            # nozzle under test closed: it reads minus the thrust
    clk.t += 10
    assert parse_weight_line(es.command("IP")).value == pytest.approx(-truth, abs=0.006)
    assert es.command("2U") == b"OK!\r\n" and es.command("PU") == b"kg\r\n"
    assert es.command("PV").startswith(b"SCOUT")
    for bad in (b"XX", b"ip", b"99U"):
        assert es.command(bad.decode()) == b"ES\r\n"


def test_scout_emulator_noise_garbage_seeded():
    a = EmulatedScout(None, clock=Clock(), seed=5, garbage_prob=0.2, unstable_prob=0.3)
    b = EmulatedScout(None, clock=Clock(), seed=5, garbage_prob=0.2, unstable_prob=0.3)
    la = [a.command("IP") for _ in range(200)]
    assert la == [b.command("IP") for _ in range(200)]
    kinds = [s.kind for s in a.sent]
    assert 20 < kinds.count("garbage") < 60
    parsed = [parse_weight_line(x) for x in la]
    good = [p for p in parsed if p is not None]
    assert len(good) == kinds.count("weight")       # every garbage line is rejected by the parser
    assert 0.1 < sum(not p.stable for p in good) / len(good) < 0.5
    vals = [p.value for p in good]
    mean = sum(vals) / len(vals)
    sd = math.sqrt(sum((v - mean) ** 2 for v in vals) / (len(vals) - 1))
    assert abs(mean) < 0.1 and 0.14 < sd < 0.26


def test_continuous_print_rate():
    clk = Clock()
    es = quiet_scout(clock=clk, print_rate_hz=10)
    assert es.command("CP") == b""
    lines = []
    nxt = clk.t
    while nxt < 101.0 - 1e-9:             # one second of printing: 100.0, 100.1, ..., 100.9
        clk.t = nxt
        out, nxt = es.tick(clk.t)
        lines.append(out)
    assert len([x for x in lines if x]) == 10
    es.command("0P")
    assert es.tick(clk.t + 1)[1] is None


# ------------------------------------------------------------- over ptys
@pytest.fixture
def bench_ptys():
    ev = EmulatedValveController(4)
    es = EmulatedScout(ev, seed=1, lag_s=0.02, print_rate_hz=50, garbage_prob=0.05)
    with serve_pty(ev) as sv, serve_pty(es) as ss:
        yield ev, es, sv.path, ss.path


def test_drivers_over_ptys(bench_ptys):
    ev, es, vpath, spath = bench_ptys
    with ValveController(vpath, timeout=1.0) as v, OhausScout(spath, ack_timeout=0.1) as s:
        assert v.identify().n_channels == 4
        assert s.version() == "SCOUT STX EMU 1.00"
        assert s.unit() == "g"
        assert s.zero() is True
        v.set_all([60, 60, 60, 0])
        assert v.state() == (60, 60, 60, 0)
        time.sleep(0.2)
        r = s.read("SP")
        assert r.stable and r.value == pytest.approx(ThrustTable.default().per_nozzle(60, 3), abs=1.0)
        with pytest.raises(DeviceError, match="ES"):
            s._setting("XYZ")
        vals = [r.value for r in s.readings(0.5)]
        assert 15 <= len(vals) <= 30
        assert s.n_garbage == sum(x.kind == "garbage" for x in es.sent)
        s.stop_continuous()
        v.off()
        assert ev.duties == (0, 0, 0, 0)


def test_safe_feeds_watchdog_while_alive_and_stops_when_caller_stalls(bench_ptys):
    ev, es, vpath, spath = bench_ptys
    with ValveController(vpath) as v:
        v.identify()
        with v.safe(150) as guard:
            v.set_all([50, 0, 0, 0])
            for _ in range(10):                 # 0.5 s, caller alive
                time.sleep(0.05)
                guard.heartbeat()
            assert ev.duties == (50, 0, 0, 0) and guard.feeds >= 3 and ev.watchdog_trips == 0
            time.sleep(0.5)                     # caller stuck: feeder stops, watchdog closes
            assert ev.duties == (0, 0, 0, 0) and ev.watchdog_trips == 1
        assert ev.lines[-1][1] == "STATE?" and ev.lines[-2][1] == "OFF"


def test_missing_device_is_one_line_error(tmp_path):
    with pytest.raises(DeviceError, match="cannot open the valve controller"):
        ValveController(str(tmp_path / "nope")).open()
    with pytest.raises(DeviceError, match="cannot open the OHAUS balance"):
        OhausScout("socket://127.0.0.1:1").open()


def test_pyserial_loop_url():
    with OhausScout("loop://", timeout=0.2) as s:
        # loop:// echoes what is sent: 'IP' is not a weight line, so it is garbage, then a timeout
        with pytest.raises(DeviceError, match="sent no reading"):
            s.read("IP")
        assert s.n_garbage == 1


def test_drivers_over_socket_url():
    """The Wi-Fi bridge transport: pyserial's socket:// handler against a loopback TCP emulator."""
    from bench.emulators import serve_tcp

    ev = EmulatedValveController(4)
    es = EmulatedScout(ev, seed=2, lag_s=0.0, print_rate_hz=50, garbage_prob=0.0)
    with serve_tcp(ev) as tv, serve_tcp(es) as ts:
        assert tv.url.startswith("socket://127.0.0.1:")
        with ValveController(tv.url) as v, OhausScout(ts.url) as s:
            assert v.identify().n_channels == 4
            with v.safe(300) as guard:
                v.set_duty(1, 70)
                assert s.read("IP").value == pytest.approx(ThrustTable.default().per_nozzle(70, 1), abs=1)
                vals = []
                for r in s.readings(0.3):
                    vals.append(r.value)
                    guard.heartbeat()
                assert len(vals) >= 8
            s.stop_continuous()
        assert ev.duties == (0, 0, 0, 0) and ev.lines[-1][1] == "STATE?"


def test_continuous_refused_is_a_clear_error():
    from tests.support.fakeport import ScriptedPort

    port = ScriptedPort([(b"CP\r\n", b"ES\r\n")])
    s = OhausScout(port, acquisition="continuous")
    s.start_continuous()
    with pytest.raises(DeviceError, match="refused continuous printing"):
        s.next_reading(time.monotonic() + 1)
