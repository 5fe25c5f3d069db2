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
from pathlib import Path
from typing import Any

from common.errors import UserError
from common.lowprio import LagGuard, background
from common.process_feeder import BatchFeeder

FEED_EVERY_S = 0.02
"""The calls queued by the estimator go to the recording process at this period, s."""


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
        ctx = mp.get_context("spawn")
        conn, child = ctx.Pipe()
        self._proc = ctx.Process(target=_recorder_main, name="live-recorder", daemon=True,
                                 args=(str(self.out), dict(meta), n_channels, structure, child))
        self._proc.start()
        child.close()
        self._feed = BatchFeeder(conn, self._proc, "recorder-feed", FEED_EVERY_S)
        self._calls = self._feed.queue

    @property
    def lost_calls(self) -> int:
        """Calls that could not be handed over (the process had died)."""
        return self._feed.lost

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
        with self._feed.lock:
            self._feed.send_locked()

    def idle(self) -> None:
        """The caller's loop is idle: the feeder thread may hand the calls over now
        (:meth:`common.process_feeder.BatchFeeder.idle`; the loop never waits for a pipe)."""
        self._feed.idle()

    def close(self, status: str, extra: dict[str, Any] | None = None) -> None:
        """Hand over what is queued, close the folder with ``status`` and wait for it;
        raises UserError if the recording process died."""
        if self.closed:
            return
        self.closed = True
        reply = self._feed.finish(status, extra)
        if reply is None or reply[0] != "closed":
            raise UserError(f"{self.out}: the recording process ended early (exit code "
                            f"{self._proc.exitcode}); the folder holds what it wrote before")
        self.counts = reply[1]
