"""The valve controller's replies as real boards and links deliver them.

Each case is the exact bytes a real Arduino-class board, USB-serial adapter or Wi-Fi
bridge produces, with its source beside it, and what ``bench.valves.ValveController``
must make of them. The protocol is docs/valve-protocol.md; the reference sketch is
firmware/tpods_valves/tpods_valves.ino (it answers with ``Serial.println``).
"""

from __future__ import annotations

import socket
import threading
import time

import pytest

from bench.emulators import serve_pty
from bench.emulators.valves import EmulatedValveController
from bench.valves import ValveController, clean_reply
from common.errors import DeviceError
from tests.support.fakeport import ScriptedPort

# Serial.println ends every line with "\r\n": "followed by a carriage return character
# (ASCII 13, or '\r') and a newline character (ASCII 10, or '\n')"
# (https://www.arduino.cc/en/Serial/Println). These are the reference sketch's replies.
CRLF_ID = (b"ID?\n", b"TPODS-VALVES 1.0 4\r\n")


def valves(script, **kw):
    kw.setdefault("timeout", 0.2)
    return ValveController(ScriptedPort(script), **kw)


# ----------------------------------------------------------- line endings
def test_reference_sketch_replies_with_crlf():
    # Every reply of firmware/tpods_valves/tpods_valves.ino, byte for byte: Serial.println
    # adds "\r\n"; printDuty() prints a fractional duty with Serial.print(d, 3) ("37.500").
    port = ScriptedPort([
        CRLF_ID,
        (b"FREQ 10\n", b"OK\r\n"),
        (b"DUTY 2 37.5\n", b"OK\r\n"),
        (b"WDT 500\n", b"OK\r\n"),
        (b"PING\n", b"PONG\r\n"),
        (b"STATE?\n", b"STATE 0 37.500 0 0\r\n"),
        (b"OFF\n", b"OK\r\n"),
        (b"STATE?\n", b"STATE 0 0 0 0\r\n"),
    ])
    with ValveController(port, timeout=0.2) as v:
        assert v.identify().firmware == "1.0"
        v.set_freq(10)
        v.set_duty(2, 37.5)
        v.watchdog(500)
        v.ping()
        assert v.state() == (0.0, 37.5, 0.0, 0.0)
        assert v.off_confirmed() == (0.0, 0.0, 0.0, 0.0)
    assert port.done() and v.dropped_bytes == 0 and v.skipped_lines == 0


def test_reference_sketch_err_lines_raise_with_their_text():
    # tpods_valves.ino: Serial.print("ERR channel must be 1-"); Serial.println(N_CH);
    v = valves([CRLF_ID, (b"DUTY 1 50\n", b"ERR channel must be 1-4\r\n")])
    v.identify()
    with pytest.raises(DeviceError, match="refused 'DUTY 1 50': ERR channel must be 1-4$"):
        v.set_duty(1, 50)


@pytest.mark.parametrize("reply", [
    b"OK\n",          # the protocol's own ending (docs/valve-protocol.md)
    b"OK\r\n",        # Serial.println (arduino.cc Serial.println reference)
    b"OK\r",          # Serial.print("OK\r"): CR alone ends a line for SerialLink too
    b"  OK \r\n",     # padding a hand-written firmware may add (Serial.print(" OK ")...)
    b"OK\t\r\n",
])
def test_line_endings_and_surrounding_whitespace(reply):
    v = valves([(b"OFF\n", reply)])
    v.off()


def test_internal_spacing_of_state():
    # docs/valve-protocol.md: "tokens separated by one or more spaces"
    v = valves([CRLF_ID, (b"STATE?\n", b"STATE 0  12.250\t0 0\r\n")])
    v.identify()
    assert v.state() == (0.0, 12.25, 0.0, 0.0)


# ------------------------------------------------------- bytes around a reply
def test_nul_and_0xff_bytes_before_a_reply_are_dropped_and_counted():
    # Exact bytes a pyserial user got from an Arduino after opening the port:
    # b'\x00\x00\x00\x00\xff433\r\n' (forum.arduino.cc/t/serial-communication-with-python-
    # beginner-qestion/944780). Stray NULs on open: jclark/satpulse#213 (CDC ACM),
    # florisla/stm32loader#46 (a NUL as DTR resets the MCU).
    v = valves([(b"ID?\n", b"\x00\x00\x00\x00\xffTPODS-VALVES 1.0 4\r\n")])
    assert v.identify().n_channels == 4
    assert v.dropped_bytes == 5


def test_a_line_of_nothing_but_noise_is_not_the_reply():
    v = valves([(b"OFF\n", b"\x00\x00\r\n\xff\r\nOK\r\n")])
    v.off()
    assert v.dropped_bytes == 3


def test_garbage_bytes_after_reconnect():
    # pyserial/pyserial#26: the first readline after opening returned
    # b'\xaae\xd1\xb9\xf10;0;3;0;9;gateway started...': non-ASCII bytes glued to text.
    # Dropping the non-ASCII bytes leaves printable junk ('e'), which is not a valid reply:
    # refused with the reply in the message, not guessed at.
    v = valves([(b"ID?\n", b"\xaae\xd1\xb9\xf1TPODS-VALVES 1.0 4\r\n")])
    with pytest.raises(DeviceError, match="not a TPODS valve controller: ID\\? answered 'eTPODS-VALVES 1.0 4'"):
        v.identify()


@pytest.mark.parametrize("negotiation", [
    # IAC WILL ECHO, sent by an ESP32 telnet server on connect
    # (Isysxp/PDP11-on-the-M5-Core ESP_Telnet.cpp: noecho[] = {0xFF, 0xFB, 0x01})
    b"\xff\xfb\x01",
    # IAC DO SGA, IAC WILL TTYPE/NAWS/TSPEED/LFLOW/LINEMODE/NEW-ENVIRON, IAC DO STATUS: the
    # option bytes 0x20 ' ', 0x21 '!', 0x22 '"', 0x27 "'" are printable, so dropping only
    # non-printable bytes is not enough (linuxsheet.com/answers/355775)
    b"\xff\xfd\x03\xff\xfb\x18\xff\xfb\x1f\xff\xfb\x20\xff\xfb\x21\xff\xfb\x22\xff\xfb\x27\xff\xfd\x05",
    # IAC SB ... IAC SE (a subnegotiation, RFC 854/855)
    b"\xff\xfa\x18\x01\xff\xf0",
])
def test_telnet_negotiation_from_a_wifi_bridge_is_dropped(negotiation):
    v = valves([(b"ID?\n", negotiation + b"TPODS-VALVES 1.0 4\r\n")])
    assert v.identify().n_channels == 4
    assert v.dropped_bytes == len(negotiation)


def test_clean_reply_keeps_an_escaped_ff_out():
    assert clean_reply(b"\xff\xffOK") == ("OK", 2)      # IAC IAC = data byte 0xFF: not ASCII
    assert clean_reply(b" STATE 0 0 0 0 ") == ("STATE 0 0 0 0", 0)


# ------------------------------------------------------------------- echo
def test_an_echo_of_the_command_is_skipped():
    # A firmware or bridge that echoes what it receives (the "echo-echo sketch" of
    # noopkat/avrgirl-arduino#43; a telnet bridge in echo mode, esp8266/Arduino#2729).
    # No reply of protocol v1 equals a command, so an exact echo is unambiguous.
    v = valves([(b"ID?\n", b"ID?\r\nTPODS-VALVES 1.0 4\r\n"),
                (b"DUTY* 50 50 0 0\n", b"DUTY* 50 50 0 0\r\nOK\r\n")])
    v.identify()
    v.set_all([50, 50, 0, 0])
    assert v.skipped_lines == 2


# ---------------------------------------------------------- partial lines
def test_a_reply_in_pieces_is_assembled():
    # USB CDC and TCP deliver a line in as many reads as they like (pyserial readline
    # only stops at "\n"; pyserial.com docs "Reading Data").
    port = ScriptedPort([(b"ID?\n", b"TPODS-VAL")])
    threading.Timer(0.05, port.feed, args=(b"VES 1.0", )).start()
    threading.Timer(0.10, port.feed, args=(b" 4\r\n", )).start()
    v = ValveController(port, timeout=0.5)
    assert v.identify().n_channels == 4


def test_a_reply_without_end_of_line_says_so():
    # Serial.print("OK") instead of Serial.println("OK"): the line never ends.
    v = valves([(b"OFF\n", b"OK")])
    with pytest.raises(DeviceError, match=r"answered 'OFF' with 'OK' but no end of line within 0.2 s"):
        v.off()


# -------------------------------------------------------------- lowercase
@pytest.mark.parametrize("reply, match", [
    (b"ok\r\n", "answered 'ok' to 'OFF' \\(expected OK\\)"),
    (b"err unknown command\r\n", "answered 'err unknown command' to 'OFF'"),
])
def test_lowercase_replies_are_refused_with_the_reply_in_the_message(reply, match):
    # The protocol's replies are upper case (docs/valve-protocol.md, the reference sketch);
    # a firmware answering "ok" is not protocol v1: one clear line, nothing guessed.
    v = valves([(b"OFF\n", reply)])
    with pytest.raises(DeviceError, match=match) as ei:
        v.off()
    assert "\n" not in str(ei.value)


# ------------------------------------------------------ reset when the port opens
def test_boot_sequence_exact_bytes():
    # An Uno/Nano/Mega resets when the port opens (DTR) and "waits in bootloader while you
    # send the data" (arduino.stackexchange.com/questions/58061): the first PINGs are lost,
    # a command half-heard while the sketch starts gets an ERR, a banner may be printed
    # from setup() (forum.arduino.cc/t/interesting-python-comms-problem/276880:
    # Serial.println("<Arduino is ready>")). The driver PINGs until PONG, then goes on.
    port = ScriptedPort([
        (b"PING\n", b""),                                        # in the bootloader
        (b"PING\n", b"<Arduino is ready>\r\n"),                  # banner, then nothing
        (b"PING\n", b"ERR unknown command\r\n"),                 # half-heard
        (b"PING\n", b"PONG\r\n"),
        CRLF_ID,
    ])
    v = ValveController(port, timeout=0.1, boot_s=2.0)
    assert v.identify().n_channels == 4
    assert port.done() and v.skipped_lines == 2


class ArduinoBoard:
    """The reference sketch on a board that resets when the port opens, for serve_pty.

    Bytes sent before ``boot_s`` are lost (the bootloader); ``noise`` arrives 0.1 s after
    the reset, ``banner`` at boot; replies end with ``\\r\\n`` (Serial.println).
    """

    def __init__(self, boot_s: float, banner: bytes = b"", noise: bytes = b"") -> None:
        self.valves = EmulatedValveController(4, firmware="1.0")
        self.t0 = time.monotonic()
        self.boot_s, self.banner, self.noise = boot_s, banner, noise
        self.booted = False
        self.lost = 0
        self._buf = b""

    def tick(self, now: float) -> tuple[bytes, float | None]:
        out = b""
        if self.noise and now >= self.t0 + 0.1:
            out, self.noise = self.noise, b""
        if not self.booted and now >= self.t0 + self.boot_s:
            self.booted = True
            out += self.banner
        due = ([self.t0 + 0.1] if self.noise else []) + ([] if self.booted else [self.t0 + self.boot_s])
        return out, min(due) if due else None

    def receive(self, data: bytes, now: float) -> bytes:
        out, _ = self.tick(now)
        if not self.booted:
            self.lost += len(data)
            return out
        self._buf += data
        while b"\n" in self._buf:
            raw, self._buf = self._buf.split(b"\n", 1)
            out += self.valves.process_line(raw.rstrip(b"\r").decode(), now).encode() + b"\r\n"
        return out


def test_board_that_resets_on_open_is_identified_after_it_boots():
    # Boot time 1.6 s: "the 1.5 seconds needed for the software to come up"
    # (exchangetuts.com pyserial-problem-with-arduino...), 1.2-1.9 s measured on an
    # STM32WL board (meshcore-dev/meshcore.js#27). Driver defaults, real pty.
    board = ArduinoBoard(boot_s=1.6, banner=b"TPODS valves ready\r\n", noise=b"\x00\x00\x00")
    with serve_pty(board) as srv:
        with ValveController(srv.path) as v:
            assert v.identify().n_channels == 4
            took = time.monotonic() - board.t0   # from the board's reset (its own clock), not
            # from after the pty came up: a loaded machine delays the latter past the reset
            v.set_all([50, 0, 0, 0])
            assert v.state() == (50.0, 0.0, 0.0, 0.0)
            v.off()
    assert board.lost > 0                         # commands before the boot really were lost
    assert 1.6 <= took < 2.6
    assert v.dropped_bytes + v.skipped_lines > 0  # banner / NULs seen and skipped (timing-dependent which)
    assert [line for _, line, _ in board.valves.lines][-4:] == ["ID?", "DUTY* 50 0 0 0", "STATE?", "OFF"]


def test_board_that_never_answers_is_one_clear_line():
    board = ArduinoBoard(boot_s=1e9)
    with serve_pty(board) as srv:
        with ValveController(srv.path, boot_s=0.6, timeout=0.2) as v:
            with pytest.raises(DeviceError, match=r"sent nothing in the 0\.\d s after the port opened") as ei:
                v.identify()
    assert "\n" not in str(ei.value)


def test_a_board_that_answers_at_once_costs_one_ping():
    ev = EmulatedValveController(4)
    with serve_pty(ev) as srv:
        with ValveController(srv.path) as v:
            v.identify()
    assert [line for _, line, _ in ev.lines] == ["PING", "ID?"]


def test_wifi_bridge_with_telnet_negotiation_and_echo_over_socket_url():
    # An ESP32 bridge in telnet mode (IAC WILL ECHO, Isysxp/PDP11-on-the-M5-Core
    # ESP_Telnet.cpp) that also echoes the host's line, replies with println's "\r\n",
    # through pyserial's socket:// handler.
    emu = EmulatedValveController(4, firmware="1.0")
    srv = socket.create_server(("127.0.0.1", 0))
    port = srv.getsockname()[1]

    def serve() -> None:
        conn, _ = srv.accept()
        with conn:
            first, buf = True, b""
            while True:
                data = conn.recv(4096)
                if not data:
                    return
                buf += data
                while b"\n" in buf:
                    raw, buf = buf.split(b"\n", 1)
                    out = (b"\xff\xfb\x01\xff\xfb\x03" if first else b"") + raw + b"\r\n"
                    out += emu.process_line(raw.decode()).encode() + b"\r\n"
                    first = False
                    conn.sendall(out)

    th = threading.Thread(target=serve, daemon=True)
    th.start()
    try:
        with ValveController(f"socket://127.0.0.1:{port}") as v:
            assert v.identify().n_channels == 4
            v.set_duty(3, 40)
            assert v.state() == (0.0, 0.0, 40.0, 0.0)
        assert v.dropped_bytes == 6 and v.skipped_lines == 4   # PING ID? DUTY STATE? echoes
    finally:
        srv.close()
        th.join(timeout=2)
