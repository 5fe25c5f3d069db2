"""Exact expected-exchange tests: the bytes each driver sends and how it takes each reply."""

import pytest

from bench.ohaus.driver import OhausScout
from bench.valves import ValveController
from common.errors import DeviceError, UserError
from tests.support.fakeport import ScriptedPort

ID = (b"ID?\n", b"TPODS-VALVES 1.2 4\r\n")


def valves(script, **kw):
    return ValveController(ScriptedPort(script), timeout=0.2, **kw)


# ------------------------------------------------------------------- valves
def test_valve_commands_exact_bytes():
    port = ScriptedPort([
        ID,
        (b"FREQ 10\n", b"OK\n"),
        (b"DUTY 2 37.5\n", b"OK\n"),
        (b"DUTY* 10 0 90 12.25\n", b"OK\n"),
        (b"WDT 500\n", b"OK\n"),
        (b"PING\n", b"PONG\n"),
        (b"STATE?\n", b"STATE 10 0 90 12.25\n"),
        (b"OFF\n", b"OK\n"),
    ])
    with ValveController(port, timeout=0.2) as v:
        ident = v.identify()
        assert (ident.model, ident.firmware, ident.n_channels) == ("TPODS-VALVES", "1.2", 4)
        v.set_freq(10)
        v.set_duty(2, 37.5)
        v.set_all([10, 0, 90, 12.25])
        v.watchdog(500)
        v.ping()
        assert v.state() == (10.0, 0.0, 90.0, 12.25)
        v.off()
    assert port.done() and port.closed


def test_valve_err_reply_raises_device_error():
    v = valves([ID, (b"DUTY 1 50\n", b"ERR valve 1 overheated\n")])
    v.identify()
    with pytest.raises(DeviceError, match="overheated"):
        v.set_duty(1, 50)


def test_valve_silence_is_a_clear_timeout():
    v = valves([(b"ID?\n", b"")])
    with pytest.raises(DeviceError, match="did not answer 'ID\\?' within 0.2 s"):
        v.identify()


def test_valve_wrong_device_and_wrong_replies():
    with pytest.raises(DeviceError, match="not a TPODS valve controller"):
        valves([(b"ID?\n", b"      12.34 g\r\n")]).identify()
    v = valves([ID, (b"OFF\n", b"PONG\n")])
    v.identify()
    with pytest.raises(DeviceError, match="expected OK"):
        v.off()
    v = valves([ID, (b"STATE?\n", b"STATE 0 0\n")])
    v.identify()
    with pytest.raises(DeviceError, match="STATE"):
        v.state()


def test_valve_limits_refused_before_sending():
    port = ScriptedPort([ID])
    v = ValveController(port, timeout=0.2, duty_limits=(10, 90))
    v.identify()
    for ch, pct in ((1, 95), (1, 5), (5, 50), (1, -1), (1, float("nan"))):
        with pytest.raises(UserError):
            v.set_duty(ch, pct)
    with pytest.raises(UserError):
        v.set_all([50, 50, 50])
    with pytest.raises(UserError):
        v.set_freq(0.5)
    assert port.written == [b"ID?\n"]  # nothing else went out


def test_safe_closes_and_confirms_on_exception():
    port = ScriptedPort([
        ID,
        (b"OFF\n", b"OK\n"), (b"WDT 400\n", b"OK\n"),
        (b"DUTY* 50 50 0 0\n", b"OK\n"),
        (b"OFF\n", b"OK\n"), (b"STATE?\n", b"STATE 0 0 0 0\n"),
    ])
    v = ValveController(port, timeout=0.2)
    v.identify()
    with pytest.raises(RuntimeError, match="boom"):
        with v.safe(400, feed_every_s=100) as guard:
            v.set_all([50, 50, 0, 0])
            raise RuntimeError("boom")
    assert port.done()
    assert guard.final_state == (0.0, 0.0, 0.0, 0.0)


def test_safe_retries_off_until_state_confirms():
    port = ScriptedPort([
        ID, (b"OFF\n", b"OK\n"), (b"WDT 400\n", b"OK\n"),
        (b"OFF\n", b"OK\n"), (b"STATE?\n", b"STATE 0 30 0 0\n"),    # a stuck channel
        (b"OFF\n", b"garbage\n"),                                   # a bad reply
        (b"OFF\n", b"OK\n"), (b"STATE?\n", b"STATE 0 0 0 0\n"),
    ])
    v = ValveController(port, timeout=0.2)
    v.identify()
    with v.safe(400, feed_every_s=100):
        pass
    assert port.done()


def test_safe_reports_unconfirmed_close():
    port = ScriptedPort([ID, (b"OFF\n", b"OK\n"), (b"WDT 400\n", b"OK\n")]
                        + [(b"OFF\n", b"OK\n"), (b"STATE?\n", b"STATE 0 30 0 0\n")] * 3)
    v = ValveController(port, timeout=0.2)
    v.identify()
    with pytest.raises(DeviceError, match="CLOSE THE AIR SUPPLY"):
        with v.safe(400, feed_every_s=100):
            pass


# ------------------------------------------------------------------ balance
def scout(script, **kw):
    kw.setdefault("timeout", 0.2)
    kw.setdefault("ack_timeout", 0.05)
    return OhausScout(ScriptedPort(script), **kw)


def test_scout_reads_exact_bytes():
    s = scout([
        (b"IP\r\n", b"      12.34 g\r\n"),
        (b"P\r\n", b"      12.35 g ?\r\n"),
        (b"SP\r\n", b"      12.36 g\r\n"),
    ])
    r = s.read("IP")
    assert (r.value, r.unit, r.stable) == (12.34, "g", True)
    r = s.read("P")
    assert (r.value, r.stable) == (12.35, False)
    assert s.read("SP").value == 12.36


def test_scout_skips_and_counts_garbage():
    s = scout([(b"IP\r\n", b"\x00\xff\r\n  12.3\r\n#?!\r\n     -1.50 g ?\r\n")])
    r = s.read("IP")
    assert (r.value, r.stable) == (-1.5, False)
    assert s.n_garbage == 3 and s.garbage_examples[1] == b"  12.3"


def test_scout_es_refusal():
    s = scout([(b"SP\r\n", b"ES\r\n"), (b"Z\r\n", b"ES\r\n"), (b"9U\r\n", b"ES\r\n")])
    with pytest.raises(DeviceError, match="refused 'SP' \\(ES\\)"):
        s.read("SP")
    with pytest.raises(DeviceError, match="refused 'Z'"):
        s.zero()
    with pytest.raises(DeviceError, match="refused '9U'"):
        s.set_unit(9)


def test_scout_silence_is_a_clear_timeout():
    s = scout([(b"IP\r\n", b"")])
    with pytest.raises(DeviceError, match="sent no reading after 'IP' within 0.2 s"):
        s.read("IP")
    s = scout([(b"IP\r\n", b"#?!\r\n")])  # only garbage: also a timeout
    with pytest.raises(DeviceError, match="sent no reading"):
        s.read("IP")


def test_scout_settings_and_info():
    s = scout([
        (b"Z\r\n", b"OK!\r\n"),
        (b"T\r\n", b""),                       # no acknowledgement: still fine
        (b"1U\r\n", b"OK!\r\n"),
        (b"PU\r\n", b"g\r\n"),
        (b"PV\r\n", b"SCOUT STX\r\nSW 1.10\r\n"),
    ])
    assert s.zero() is True
    assert s.tare() is False
    assert s.set_unit("g") is True
    assert s.unit() == "g"
    assert s.version() == "SCOUT STX | SW 1.10"
    with pytest.raises(UserError):
        s.read("XP")
    with pytest.raises(UserError):
        s.set_unit("furlong")


def test_scout_continuous_stream_and_lost_balance():
    port = ScriptedPort([(b"CP\r\n", b""), (b"0P\r\n", b"")])
    s = OhausScout(port, silence_timeout=0.3, acquisition="continuous")
    s.start_continuous()
    port.feed(b"      1.00 g\r\n  garb\r\n      2.00 g ?\r\nOK!\r\n      3.")
    import time
    got = []
    end = time.monotonic() + 0.1
    while (r := s.next_reading(end)) is not None:
        got.append((r.value, r.stable))
    assert got == [(1.0, True), (2.0, False)]
    assert s.n_garbage == 1
    port.feed(b"00 g\r\n")                    # the partial line completes
    assert s.next_reading(time.monotonic() + 0.1).value == 3.0
    with pytest.raises(DeviceError, match="went silent"):
        s.next_reading(time.monotonic() + 5.0)
    with pytest.raises(UserError):
        s.read("IP")                           # continuous printing is on
    s.stop_continuous()
    assert port.done()
