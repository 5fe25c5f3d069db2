"""Balances without continuous print: the driver polls with IP (exact bytes, ptys, a session)."""

import math
import subprocess
import threading
import time

import pandas as pd
import pytest

from bench.emulators import EmulatedScout, serve_pty
from bench.fit import fit_steps
from bench.ohaus.driver import OhausScout, parse_weight_line
from bench.session import SessionConfig, read_session, run_session
from bench.valves import ValveController
from common.errors import DeviceError, UserError
from common.thrust_table import ThrustTable
from tests.support.bench import Bench, run_json
from tests.support.fakeport import ScriptedPort

IP = b"IP\r\n"


def line(value: float, unstable: bool = False) -> bytes:
    return f"{value:10.2f} g{' ?' if unstable else ''}\r\n".encode()


WARMUP = [(IP, line(i)) for i in (1, 2, 3, 4, 5)]   # the five IP that measure the poll rate


def polling(script, **kw):
    """A Scout that refused CP and is polling; the warm-up readings already taken."""
    port = ScriptedPort([(b"CP\r\n", b"ES\r\n")] + WARMUP + list(script))
    kw.setdefault("timeout", 0.3)
    s = OhausScout(port, **kw)
    s.start_continuous()
    assert [r.value for r in s.received()] == [1, 2, 3, 4, 5]
    return s, port


# ----------------------------------------------------------- exact bytes
def test_auto_falls_back_to_ip_when_cp_gets_es():
    port = ScriptedPort([(b"CP\r\n", b"ES\r\n")] + WARMUP + [
        (IP, line(6, unstable=True)),
        (IP, b"#?!\r\n"),                 # a garbled reply: counted, asked again
        (IP, line(7)),
    ])
    s = OhausScout(port)
    s.start_continuous()
    assert port.written == [b"CP\r\n"] + [IP] * 5
    assert (s.mode_in_use, s.fallback_reason, s.continuous, s.acquiring) == ("poll", "ES to CP", False, True)
    assert math.isfinite(s.poll_rate_hz) and s.poll_rate_hz > 0
    assert s.fallback_message == ("balance refused continuous print (ES to CP): polling with IP at "
                                  f"~{s.poll_rate_hz:.0f} readings/s")
    t_before = time.monotonic()
    got = [s.next_reading(time.monotonic() + 1.0) for _ in range(7)]
    assert [(r.value, r.stable) for r in got] == [(1, True), (2, True), (3, True), (4, True), (5, True),
                                                  (6, False), (7, True)]
    assert got[-1].t >= got[-2].t >= t_before            # host time of arrival
    assert s.n_garbage == 1 and s.garbage_examples == [b"#?!"]
    assert port.done()
    assert s.received() == []                            # nothing buffered, nothing sent
    s.stop_continuous()                                  # no 0P: printing never started
    assert len(port.written) == 9 and not s.acquiring
    info = s.acquisition_info()
    assert (info["requested"], info["mode"], info["fallback"]) == ("auto", "poll", "ES to CP")


def test_auto_falls_back_when_cp_prints_nothing():
    port = ScriptedPort([(b"CP\r\n", b""), (b"0P\r\n", b"")] + WARMUP)
    s = OhausScout(port, probe_s=0.1)
    t0 = time.monotonic()
    s.start_continuous()
    assert 0.1 <= time.monotonic() - t0 < 1.0
    assert port.written == [b"CP\r\n", b"0P\r\n"] + [IP] * 5 and port.done()
    assert s.mode_in_use == "poll" and s.fallback_reason == "no reading within 0.1 s"
    assert s.fallback_message.startswith("balance printed nothing after CP (no reading within 0.1 s): "
                                         "polling with IP at ~")


def test_auto_keeps_continuous_print_when_the_balance_prints():
    port = ScriptedPort([(b"CP\r\n", line(1) + b"garb\r\n" + line(2)), (b"0P\r\n", b"")])
    s = OhausScout(port)
    s.start_continuous()
    assert (s.mode_in_use, s.fallback_reason, s.continuous) == ("continuous", None, True)
    assert s.fallback_message is None
    assert s.next_reading(time.monotonic() + 0.5).value == 1   # the probe's reading is kept
    assert [r.value for r in s.received()] == [2] and s.n_garbage == 1
    s.stop_continuous()
    assert port.done()


def test_poll_mode_sends_ip_only():
    port = ScriptedPort(WARMUP + [(IP, line(6))])
    s = OhausScout(port, acquisition="poll")
    s.start_continuous()
    assert s.fallback_reason is None and s.fallback_message is None and s.mode_in_use == "poll"
    assert [s.next_reading(time.monotonic() + 1).value for _ in range(6)] == [1, 2, 3, 4, 5, 6]
    assert port.written == [IP] * 6 and port.done()
    with pytest.raises(UserError):
        OhausScout(port, acquisition="sometimes")


def test_poll_reply_in_flight_at_the_deadline_stays_in_its_window():
    s, port = polling([(IP, b"")])
    t0 = time.monotonic()
    threading.Timer(0.1, port.feed, [line(8)]).start()    # slow this time (re-ask only after 0.25 s)
    r = s.next_reading(t0 + 0.03)
    assert r is not None and r.value == 8 and r.t >= t0 + 0.1    # waited past the deadline
    assert s.next_reading(-math.inf) is None
    # a window shorter than the measured round trip sends nothing and returns at its end
    n = len(port.written)
    t1 = time.monotonic()
    assert s.next_reading(t1 + 0.01) is None
    assert len(port.written) == n and time.monotonic() - t1 < 0.2
    assert s.n_poll_timeouts == 0 and s.n_late_replies == 0


def test_poll_late_reply_is_dropped_and_counted_and_lost_ip_is_resent():
    s, port = polling([(IP, line(1.5)), (IP, b""), (IP, line(2))])
    port.feed(line(9))                      # a reading nobody asked for (a very late reply)
    assert s.next_reading(time.monotonic() + 1).value == 1.5
    assert s.n_late_replies == 1
    t0 = time.monotonic()
    r = s.next_reading(time.monotonic() + 1)   # the first IP is never answered: sent again
    assert r.value == 2 and s.n_poll_timeouts == 1
    assert s.poll_reply_timeout <= time.monotonic() - t0 < 1.0
    assert port.done()


def test_poll_lost_balance_refused_ip_and_garbage_only():
    s, port = polling([(IP, b"")] * 5, silence_timeout=0.6)   # IP at 0, 0.25, 0.5 s
    with pytest.raises(DeviceError, match=r"went silent: no valid reading for 0.6 s \(\d IP unanswered\)"):
        s.next_reading(time.monotonic() + 5)
    assert 2 <= len(port.written) - 6 <= 3
    s, port = polling([(IP, b"#?!\r\n")] * 3 + [(IP, b"")] * 2, silence_timeout=0.4)
    with pytest.raises(DeviceError, match="went silent"):   # garbage is no sign of life
        s.next_reading(time.monotonic() + 5)
    assert s.n_garbage == 3
    s, port = polling([(IP, b"ES\r\n")])
    with pytest.raises(DeviceError, match="refused 'IP'"):
        s.next_reading(time.monotonic() + 5)
    port = ScriptedPort([(b"CP\r\n", b"ES\r\n"), (IP, b"ES\r\n")])
    with pytest.raises(DeviceError, match=r"refused continuous print \(ES to CP\) and polling with IP "
                                          r"failed: OHAUS balance refused 'IP'"):
        OhausScout(port).start_continuous()


def test_continuous_mode_keeps_es_an_error():
    port = ScriptedPort([(b"CP\r\n", b"ES\r\n")])
    s = OhausScout(port, acquisition="continuous")
    s.start_continuous()
    assert port.written == [b"CP\r\n"] and s.mode_in_use == "continuous"
    with pytest.raises(DeviceError, match="refused continuous printing.*auto or poll acquisition mode"):
        s.next_reading(time.monotonic() + 1)


# --------------------------------------------------------------- emulator
def test_emulator_can_refuse_continuous_print():
    es = EmulatedScout(None, load_g=10.0, noise_g=0.0, garbage_prob=0.0, continuous_print=False,
                       clock=lambda: 5.0)
    assert es.command("CP") == b"ES\r\n" and es.command("2P") == b"ES\r\n"
    assert es.tick(5.0) == (b"", None)                     # nothing scheduled
    assert parse_weight_line(es.command("IP")).value == 10.0
    assert es.command("0P") == b""
    assert EmulatedScout(None, clock=lambda: 5.0).command("CP") == b""   # the default prints


def test_poll_readings_over_a_pty_every_line_accounted():
    es = EmulatedScout(None, load_g=50.0, continuous_print=False, garbage_prob=0.05, seed=3)
    with serve_pty(es) as srv, OhausScout(srv.path) as s:
        vals = [(r.value, r.stable) for r in s.readings(0.3)]
        assert s.mode_in_use == "poll" and s.fallback_reason == "ES to CP"
        s.stop_continuous()
    sent = [(parse_weight_line(x.data).value, parse_weight_line(x.data).stable)
            for x in es.sent if x.kind == "weight"]
    assert len(vals) >= 20 and vals == sent               # every reply, in order, none lost
    assert s.n_garbage == sum(x.kind == "garbage" for x in es.sent)
    assert s.n_dropped == 0 and s.n_late_replies == 0


def test_poll_rate_at_9600_baud_is_wire_bound():
    """A paced pty: one exchange is 4 + 14 bytes of 10 bits, 18.75 ms: at most 53.3 readings/s."""
    es = EmulatedScout(None, load_g=100.0, continuous_print=False, garbage_prob=0.0, seed=4)
    with serve_pty(es, baud=9600) as srv, OhausScout(srv.path) as s:
        s.start_continuous()
        assert len(s.received()) == 5                      # the rate probe's readings
        n, t0 = 0, time.monotonic()
        while s.next_reading(t0 + 1.0) is not None:
            n += 1
        rate = n / (time.monotonic() - t0)
    print(f"poll rate at 9600 baud: {rate:.1f} readings/s (start estimate {s.poll_rate_hz:.1f})")
    assert 15 < rate <= 9600 / 10 / 18 + 0.5
    assert 15 < s.poll_rate_hz <= 9600 / 10 / 18 + 0.5


# ---------------------------------------------------------------- session
def test_session_against_a_balance_without_continuous_print(tpods_exe, tmp_path):
    b = Bench(seed=5, scale_baud=9600, continuous_print=False)
    out = tmp_path / "run"
    try:
        v, s = b.paths
        r = subprocess.run([tpods_exe, "bench", "characterize", "--valves", v, "--scale", s,
                            "--nozzles", "1,2", "--duty", "30,60,90", "--dwell", "0.25", "--settle", "0.1",
                            "--zero-settle", "0.1", "--zero-dwell", "0.15", "--zero-every", "3",
                            "--scale-poll-interval", "0", "--out", str(out),
                            "--no-progress"], capture_output=True, text=True, timeout=60)
    finally:
        b.stop()
    assert r.returncode == 0, r.stderr
    assert "balance refused continuous print (ES to CP): polling with IP at ~" in r.stderr
    meta = run_json(out)
    acq = meta["devices"]["scale"]["acquisition"]
    assert meta["status"] == "success" and meta["valves_closed_confirmed"] is True
    assert (acq["requested"], acq["mode"], acq["fallback"]) == ("auto", "poll", "ES to CP")
    assert 15 < acq["poll_rate_hz"] < 54 and 10 < acq["achieved_rate_hz"] < 54
    # every reading the balance sent is recorded, in order, in the window in which it was
    # taken: the valves were in that step's state when the balance measured it
    raw = pd.read_csv(out / "raw.csv")
    weights = [x for x in b.scout.sent if x.kind == "weight"]
    assert [round(v, 2) for v in raw["reading_gf"]] == [parse_weight_line(x.data).value for x in weights]
    for (_, row), x in zip(raw.iterrows(), weights, strict=True):
        state = b.state_at(x.t)
        if row["phase"] == "dwell":
            assert state[0] == row["duty_pct"] and sum(d > 0 for d in state) == row["n_open"]
        elif row["phase"] == "zero":
            assert not any(state)
    _, steps = read_session(out)
    assert len(steps) == 6 and (steps["n"] >= 5).all()
    table = ThrustTable.default()
    truth = [float(table.per_nozzle(d, k)) for k, d in zip(steps["n_open"], steps["duty_pct"], strict=True)]
    assert (abs(steps["thrust_gf"] - truth) < 0.5).all()
    fit = fit_steps(steps, 2)
    assert sorted(fit.selected) == [1, 2]


def test_session_in_continuous_mode_fails_clearly_and_closes(tmp_path):
    b = Bench(continuous_print=False)
    cfg = SessionConfig(nozzles=(1,), duties_pct=(50,), dwell_s=0.2, settle_s=0.1, zero_settle_s=0.1,
                        zero_dwell_s=0.1, watchdog_ms=300)
    try:
        v, s = b.paths
        with pytest.raises(DeviceError, match="refused continuous printing"):
            with ValveController(v) as valves, OhausScout(s, acquisition="continuous") as scale:
                run_session(valves, scale, cfg, tmp_path / "run", progress=False)
        assert b.valves.duties == (0, 0, 0, 0)
    finally:
        b.stop()
    meta = run_json(tmp_path / "run")
    assert meta["status"] == "failed" and "refused continuous printing" in meta["error"]
    assert meta["devices"]["scale"]["acquisition"]["mode"] == "continuous"
