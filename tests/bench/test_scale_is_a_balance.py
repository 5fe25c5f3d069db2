"""Issue 16: a valve controller given as --scale is named as such at once (was: 45 s of
retries, then "is the load steady?")."""

from __future__ import annotations

import time

import pytest

from bench.emulators import EmulatedValveController, serve_pty
from bench.ohaus.driver import NotABalance, OhausScout
from tpods.cli import main


@pytest.fixture
def two_valve_controllers():
    a, b = serve_pty(EmulatedValveController(4)), serve_pty(EmulatedValveController(4))
    try:
        yield a.path, b.path
    finally:
        a.stop()
        b.stop()


def test_driver_names_the_valve_controllers_reply(two_valve_controllers):
    _, wrong = two_valve_controllers
    with OhausScout(wrong, timeout=2.0) as scale:
        t0 = time.monotonic()
        with pytest.raises(NotABalance, match=r"\(--scale\) does not answer like an OHAUS balance: it "
                                              r"answered 'ERR unknown command IP', a TPODS valve "
                                              r"controller's reply"):
            scale.read("IP")
        assert time.monotonic() - t0 < 1.5  # at the first reply, not after the timeout
        with pytest.raises(NotABalance, match="'ERR unknown command PU'"):
            scale.unit()


def test_calibrate_mass_with_a_valve_controller_as_scale(two_valve_controllers, capsys):
    _, wrong = two_valve_controllers
    assert main(["calibrate", "mass", "--scale", wrong, "--readings", "3", "--timeout", "2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"tpods: error: the device at {wrong} (--scale) does not "
                                               "answer like an OHAUS balance: it answered 'ERR unknown "
                                               "command SP'"), err
    assert "steady" not in err[0]


def test_characterize_with_a_valve_controller_as_scale(two_valve_controllers, capsys, tmp_path):
    valves, wrong = two_valve_controllers
    status = main(["bench", "characterize", "--valves", valves, "--scale", wrong, "--nozzles", "1",
                   "--duty", "50:50:10", "--dwell", "1", "--settle", "0.2", "--out", str(tmp_path / "s")])
    err = capsys.readouterr().err
    assert status == 2, err
    last = err.strip().splitlines()[-1]
    assert last.startswith(f"tpods: error: the device at {wrong} (--scale) does not answer like an OHAUS "
                           "balance"), err


class _Chatty:
    """A device that answers every line with a line no balance prints."""

    def receive(self, data: bytes, now: float) -> bytes:
        return b"HELLO 42 widgets\r\n" * data.count(b"\n")

    def tick(self, now: float):
        return b"", None


def test_calibrate_mass_with_an_unknown_device_as_scale(capsys):
    server = serve_pty(_Chatty())
    try:
        t0 = time.monotonic()
        assert main(["calibrate", "mass", "--scale", server.path, "--readings", "3", "--timeout", "0.3"]) == 2
        assert time.monotonic() - t0 < 5
    finally:
        server.stop()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0] == (
        f"tpods: error: the device at {server.path} (--scale) does not answer like an OHAUS balance: 2 "
        "replies that are not weight lines, the last 'HELLO 42 widgets' (is it the balance, at "
        "--baudrate 9600, --bytesize 8, --parity N?)"), err
