"""Serial transcripts: every chunk a serial link writes or reads, byte-exact, with its time.

Format (docs/recordings.md, "Serial transcripts"): JSON Lines, UTF-8 (in practice
ASCII). The first line is the header::

    {"format": "tpods.serial/1", "device": "valve controller", "url": "/dev/ttyACM0",
     "settings": {"baudrate": 115200, ...}, "poll_s": 0.02, "opened_unix": 1790000000.123,
     "t_open_monotonic": 81234.5678, "keepalive": "PING\\n"}

then one line per chunk, in the order the host saw them::

    {"t": 0.0123, "dir": "tx", "hex": "49443f0a", "ascii": "ID?\\n"}
    {"t": 0.0131, "dir": "rx", "hex": "54504f44532d56414c564553...", "ascii": "TPODS-VALVES 1.0 4\\r\\n"}

``t`` is seconds since the port was opened on the host's monotonic clock (``tx``: when
the write returned; ``rx``: when the read that returned the bytes came back), written
as the shortest repr of the float so that ``t_open_monotonic + t`` gives the host's time
again; ``hex`` is the exact bytes; ``ascii`` is the same bytes for people (Latin-1,
JSON-escaped: ``\\r``, ``\\n``, ``\\u0000``), never read back; ``"ready": true`` marks
received bytes that were already waiting when the host asked (it did not wait for them). ``keepalive`` (optional)
is the command the driver sends from a thread at times the scheduler decides (the valve
controller's watchdog ``PING``): a strict replay does not require those at the same
places.

Every line is written and flushed at once (no buffer beyond the line): a killed process
loses at most the line being written. Cost: a few microseconds per chunk
(``make bench``: characterisation with capture on/off).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

from common.errors import UserError

FORMAT = "tpods.serial/1"
SUFFIX = ".serial.jsonl"

_dumps = json.dumps
_READY = ',"ready":true'


class Transcript:
    """Writes one serial transcript (see the module docstring)."""

    def __init__(self, path: str | Path, *, device: str, url: str, settings: dict[str, Any],
                 t_open: float, poll_s: float | None = None, keepalive: bytes | None = None) -> None:
        self.path = Path(path)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._f = open(self.path, "w", encoding="utf-8", newline="\n")  # noqa: SIM115
        except OSError as exc:
            raise UserError(f"cannot write the serial capture {self.path}: {exc.strerror or exc}") from None
        self.t_open = t_open
        header = {"format": FORMAT, "device": device, "url": url,
                  "settings": {k: v for k, v in settings.items() if _jsonable(v)},
                  "poll_s": poll_s, "opened_unix": time.time(), "t_open_monotonic": t_open}
        if keepalive:
            header["keepalive"] = keepalive.decode("latin-1")
        self._line(_dumps(header))
        self.n_chunks = 0

    def _line(self, text: str) -> None:
        f = self._f
        f.write(text + "\n")
        f.flush()

    def chunk(self, t: float, direction: str, data: bytes, ready: bool = False,
              t_call: float | None = None) -> None:
        """One chunk ``data`` sent (``"tx"``) or received (``"rx"``) at host time ``t``;
        ``ready``: received bytes that were already waiting when the host asked;
        ``t_call``: when the read that returned them (or timed out: ``b""``) was issued."""
        f = self._f
        if f.closed:
            return
        extra = _READY if ready else ("" if t_call is None else f',"t_call":{t_call - self.t_open!r}')
        f.write(f'{{"t":{t - self.t_open!r},"dir":"{direction}","hex":"{data.hex()}",'
                f'"ascii":{_dumps(data.decode("latin-1"))}{extra}}}\n')
        f.flush()
        self.n_chunks += 1

    def close(self) -> None:
        if not self._f.closed:
            self._f.close()


def _jsonable(v: Any) -> bool:
    return v is None or isinstance(v, (bool, int, float, str))


def capture_path(target: str | Path, default_name: str) -> Path:
    """Where a capture goes: ``target`` itself when it names a ``.jsonl`` file, else
    ``target/default_name`` (a folder)."""
    p = Path(target)
    if p.name.endswith(".jsonl"):
        return p
    return p / default_name


def capture_folder(path: str | Path, force: bool, command: str) -> Path:
    """A ``--capture DIR`` for serial transcripts: created if needed; transcripts already in it
    are replaced only with ``force``. UserError (one line) otherwise."""
    d = Path(path)
    if d.name.endswith((".jsonl", ".json")):
        raise UserError(f"--capture {path} names a file; {command} writes its transcripts "
                        "(*.serial.jsonl) into a folder: give a folder name")
    if d.exists() and not d.is_dir():
        raise UserError(f"--capture {path}: not a folder")
    there = sorted(p.name for p in d.glob("*" + SUFFIX)) if d.is_dir() else []
    if there and not force:
        raise UserError(f"--capture {path} already holds {', '.join(there)}; add --force to replace "
                        "them or choose another folder")
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"--capture {path}: cannot create the folder ({exc.strerror or exc})") from None
    return d


def read_transcript(path: str | Path) -> tuple[dict[str, Any], list[tuple[float, str, bytes, bool, float | None]]]:
    """``(header, [(t, dir, bytes, ready, t_call), ...])`` of a transcript; UserError naming the line
    for anything that is not one."""
    p = Path(path)
    try:
        lines = p.read_text(encoding="utf-8").splitlines()
    except FileNotFoundError:
        raise UserError(f"{p}: no such serial transcript") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise UserError(f"{p}: unreadable serial transcript ({exc})") from None
    header: dict[str, Any] | None = None
    events: list[tuple[float, str, bytes, bool, float | None]] = []
    for i, text in enumerate(lines, 1):
        if not text.strip():
            continue
        try:
            obj = json.loads(text)
            if header is None:
                if obj.get("format") != FORMAT:
                    raise ValueError(f"the first line is not a {FORMAT} header")
                header = obj
                continue
            d = obj["dir"]
            if d not in ("tx", "rx"):
                raise ValueError(f"dir must be tx or rx, not {d!r}")
            tc = obj.get("t_call")
            events.append((float(obj["t"]), d, bytes.fromhex(obj["hex"]), bool(obj.get("ready")),
                           None if tc is None else float(tc)))
        except json.JSONDecodeError:
            if i == len(lines):  # a line cut by a kill: the rest is still a transcript
                break
            raise UserError(f"{p}: line {i}: not JSON") from None
        except (ValueError, KeyError, TypeError, AttributeError) as exc:
            raise UserError(f"{p}: line {i}: not a transcript line ({exc})") from None
    if header is None:
        raise UserError(f"{p}: empty serial transcript (no {FORMAT} header)")
    return header, events
