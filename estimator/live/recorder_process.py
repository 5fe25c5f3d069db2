"""The live estimator's run folder written by a process of its own, fed in batches.

:class:`LiveRecorder` formats and writes a CSV row for every pose, command and estimate:
about 25 us of Python per pose at 1 kHz. :class:`RecorderProcess` has the calls the
estimator makes on a recorder (``command``, ``pose``, ``estimate``, ``seal``) and
``close``, but only appends each call to a list on the estimator's thread; a feeder
thread hands the list to a spawned process every :data:`FEED_EVERY_S` (one pipe write
per batch), and that process runs an ordinary :class:`LiveRecorder` on it, so the folder
is the same, file for file.

- The hand-over starts when the caller's loop is idle (:meth:`RecorderProcess.idle`,
  which :func:`estimator.live.zenoh_run.run_live` calls once its input queue is empty:
  between two poses, not while one waits): it wakes the feeder thread, which pickles and
  writes the batch (a full pipe blocks that thread, never the loop); without a wake-up
  the thread hands over what waited one and a half periods (a loop that does not idle).
- The folder is checked in the caller (``UserError`` at once: cannot be created, already
  holds a run); the process creates the files when it has started (a few tenths of a
  second; what arrives meanwhile waits in the pipe).
- Killed caller (SIGKILL): the process sees the pipe close, writes every call it received
  and closes the files; ``run.json`` keeps status ``running`` (the estimator died), and
  the folder is a valid run up to what was handed over: at most 2.5 :data:`FEED_EVERY_S`
  (50 ms) before the kill is lost on top of what :class:`LiveRecorder` itself would lose (the
  poses after the last command or hold). Ctrl-C reaches the caller only: the process
  ignores SIGINT and ends when the caller closes it.
- A process that dies (a full disk): the next hand-over fails and :meth:`close` raises
  :class:`common.errors.UserError` naming the folder.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import signal
import threading
import time
from collections import deque
from pathlib import Path
from typing import Any

from common.errors import UserError
from common.lowprio import LagGuard, background

FEED_EVERY_S = 0.02
"""The calls queued by the estimator go to the recording process at this period, s."""
CLOSE_TIMEOUT_S = 60.0


def check_folder(out: str | Path) -> Path:
    """Create ``out`` and refuse one that already holds a run (as :class:`LiveRecorder`
    does, said in the caller's process)."""
    out = Path(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"{out}: cannot create the output folder ({exc.strerror})") from None
    if (out / "poses.csv").exists():
        raise UserError(f"{out} already holds a run (poses.csv); choose another --out")
    return out


def _recorder_main(out: str, meta: dict[str, Any], n_channels: int, structure: Any,
                   conn) -> None:
    """The recording process: batches of ``(method, args)`` from ``conn`` applied to a
    :class:`LiveRecorder`; ``("close", status, extra)`` closes it and replies with its
    counts; the pipe closing (the caller died) or SIGTERM leaves the files as a kill
    would: every row received written, ``run.json`` still ``running``."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the caller's to handle
    background()  # the estimator's thread takes a core at once when it wakes
    guard = LagGuard()

    def _term(*_: object) -> None:
        raise SystemExit(143)

    signal.signal(signal.SIGTERM, _term)
    from estimator.live.recorder import LiveRecorder  # lazy: the process starts light

    rec = LiveRecorder(out, meta, n_channels=n_channels, structure=structure)
    try:
        while True:
            try:
                msg = conn.recv()
            except (EOFError, OSError):
                break
            if msg[0] == "batch":
                guard.check(msg[2])
                for name, args in msg[1]:
                    getattr(rec, name)(*args)
            elif msg[0] == "close":
                rec.close(msg[1], msg[2])
                conn.send(("closed", dict(rec.counts)))
                return
    finally:
        if not rec.closed:  # a kill of the caller: the rows written stay, no status
            for log in (rec._cmd, rec._pose, rec._est):
                with contextlib.suppress(OSError, ValueError):
                    log.close()
        conn.close()


class RecorderProcess:
    """A :class:`LiveRecorder` in a process of its own (see the module doc).

    Args:
        out: the run folder. meta: ``run.json``'s first fields. n_channels: valves per
            command. structure: a structure or vehicle (its ``structure.toml``; must
            pickle).
    """

    def __init__(self, out: str | Path, meta: dict[str, Any], n_channels: int = 4,
                 structure: Any = None) -> None:
        self.out = check_folder(out)
        self.counts: dict[str, int] = {}
        self.closed = False
        self._calls: deque[tuple[str, tuple]] = deque()
        ctx = mp.get_context("spawn")
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(target=_recorder_main, name="live-recorder", daemon=True,
                                 args=(str(self.out), dict(meta), n_channels, structure, child))
        self._proc.start()
        child.close()
        self._lock = threading.Lock()  # one sender on the pipe at a time
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._dead = False
        self._last_feed = time.monotonic()
        self.lost_calls = 0
        """Calls that could not be handed over (the process had died)."""
        self._feeder = threading.Thread(target=self._feed_loop, name="recorder-feed",
                                        daemon=True)
        self._feeder.start()

    # the estimator's calls: appended, nothing else (deque.append is atomic)
    def command(self, t: float, duty) -> None:
        """A command at lab time ``t`` (s), duties (%)."""
        self._calls.append(("command", (t, tuple(duty))))

    def pose(self, t: float, x: float, y: float, yaw: float) -> None:
        """A pose the filter used: lab time (s), x, y (m), yaw (rad)."""
        self._calls.append(("pose", (t, x, y, yaw)))

    def estimate(self, t: float, frame: int, phase: str, z, sig,
                 thrust_rel: tuple[float, float] = (0.0, 0.0), com=None) -> None:
        """An estimates.csv row (:meth:`LiveRecorder.estimate`'s arguments; the state and
        sigma arrays go as lists: they pickle several times faster)."""
        self._calls.append(("estimate", (t, frame, phase, z.tolist(), sig.tolist(),
                                         thrust_rel, com)))

    def seal(self) -> None:
        """The data are whole (:meth:`LiveRecorder.seal`): handed over at once."""
        self._calls.append(("seal", ()))
        with self._lock:
            self._send()

    # hand-over
    def _send(self) -> None:
        self._last_feed = time.monotonic()
        queued = self._calls
        calls = []
        while queued:
            calls.append(queued.popleft())
        if not calls:
            return
        if self._dead:
            self.lost_calls += len(calls)
            return
        try:
            self._conn.send(("batch", calls, time.monotonic()))
        except (OSError, ValueError):  # the process is gone: counted, said at close
            self._dead = True
            self.lost_calls += len(calls)

    def idle(self) -> None:
        """The caller's loop is idle: wake the feeder thread if the last hand-over is
        :data:`FEED_EVERY_S` old (it pickles and writes; the loop never waits for a pipe)."""
        if time.monotonic() - self._last_feed >= FEED_EVERY_S and self._calls:
            self._wake.set()

    def _feed_loop(self) -> None:
        while not self._stop.is_set():
            woke = self._wake.wait(FEED_EVERY_S)
            self._wake.clear()
            if self._stop.is_set():
                break
            if woke or time.monotonic() - self._last_feed >= 1.5 * FEED_EVERY_S:
                with self._lock:
                    self._send()

    def close(self, status: str, extra: dict[str, Any] | None = None) -> None:
        """Hand over what is queued, close the folder with ``status`` and wait for it;
        raises UserError if the recording process died."""
        if self.closed:
            return
        self.closed = True
        self._stop.set()
        self._wake.set()
        self._feeder.join(timeout=5.0)
        reply = None
        with self._lock:
            self._send()
            if not self._dead:
                try:
                    self._conn.send(("close", status, extra or {}))
                    if self._conn.poll(CLOSE_TIMEOUT_S):
                        reply = self._conn.recv()
                except (OSError, EOFError):
                    reply = None
            self._conn.close()
        self._proc.join(CLOSE_TIMEOUT_S)
        if self._proc.is_alive():
            self._proc.kill()
            self._proc.join(5.0)
        if reply is None or reply[0] != "closed":
            raise UserError(f"{self.out}: the recording process ended early (exit code "
                            f"{self._proc.exitcode}); the folder holds what it wrote before")
        self.counts = reply[1]
