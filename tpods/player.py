"""The input player: play a duty sequence on a module's valves and announce each command.

:func:`play` sends each row of an input sequence to a protocol-v1 valve controller
(``DUTY*``) at its time on the lab clock, records it in ``commands.csv`` (flushed per
row) and publishes it on ``tpods/<body>/cmd``. Safety is structural: the controller
watchdog is armed and fed only while the loop is alive (``ValveController.safe``), and
every exit path (end, Ctrl-C, SIGTERM, exception) sends OFF, confirms it with STATE?,
writes a closing all-zero row and publishes an ``end`` command.

Command payload (JSON, encoding ``application/json``), schema ``tpods.cmd/1``::

    {"schema": "tpods.cmd/1", "body": "tpods1", "seq": 17, "kind": "set",
     "t": 1763770000.123,          # lab clock (host clock at scale 1), s: when the valves switched
     "duty": [50.0, 64.1, 70.0, 64.1]}   # percent per valve, 0 = closed

``kind`` is ``set`` (a command sent to the valves), ``hold`` (the command in force,
re-announced when nothing was sent for ``heartbeat_s``: late subscribers learn the
state, and the live estimator learns that nothing changed up to ``t``) or ``end``
(all valves closed, the run is over). ``seq`` counts every message of the player.
"""

from __future__ import annotations

import contextlib
import math
import sys
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from bench.session import Terminated, ended_by
from common.errors import UserError
from common.gcpause import frozen_heap
from common.runwriter import (  # CommandLog: also tpods.player.CommandLog
    CommandLog,
    run_header,
    write_json_atomic,
)
from common.wire import (  # noqa: F401  (re-exported: the player's command API)
    CMD_KINDS,
    CMD_SCHEMA,
    DEFAULT_PREFIX,
    cmd_key,
    decode_command,
    encode_command,
)
from tpods.clock import LabClock


@dataclass
class PlayResult:
    """What :func:`play` did. Times in lab seconds."""

    status: str
    n_sent: int
    n_holds: int
    t_start: float
    t_end: float
    max_late_s: float
    final_state: tuple[float, ...] | None
    publish_errors: int = 0
    error: str | None = None
    out_dir: Path | None = None
    sent: list[tuple[float, tuple[float, ...]]] = field(default_factory=list)


def check_sequence(cmd_t: np.ndarray, duty_pct: np.ndarray, n_channels: int,
                   duty_limits: tuple[float, float]) -> None:
    """Refuse (UserError) a sequence the valves would refuse halfway through."""
    cmd_t = np.asarray(cmd_t, float)
    duty_pct = np.asarray(duty_pct, float)
    if duty_pct.ndim != 2 or len(cmd_t) != len(duty_pct) or len(cmd_t) < 1:
        raise UserError("the input must be (N,) times and (N, channels) duties")
    if duty_pct.shape[1] != n_channels:
        raise UserError(f"the input has {duty_pct.shape[1]} channels; the valve controller has "
                        f"{n_channels}")
    if not np.all(np.isfinite(cmd_t)) or np.any(np.diff(cmd_t) <= 0):
        raise UserError("input times must be finite and strictly increasing")
    lo, hi = duty_limits
    bad = (duty_pct != 0) & ((duty_pct < lo) | (duty_pct > hi))
    if np.any(bad) or not np.all(np.isfinite(duty_pct)):
        row = int(np.argwhere(bad | ~np.isfinite(duty_pct))[0][0])
        raise UserError(f"input row {row + 1}: duty outside the allowed {lo:g}-{hi:g} % "
                        "(0 closes; change --duty-limits to allow it)")


def play(valves, cmd_t, duty_pct, *, clock: LabClock | None = None,
         publish: Callable[[bytes], None] | Mapping[str, Callable[[bytes], None]] | None = None,
         body: str = "tpods1",
         out_dir: str | Path | None = None, watchdog_ms: int = 500, pwm_hz: float = 10.0,
         heartbeat_s: float = 0.1, lead_s: float = 0.2, stop: threading.Event | None = None,
         meta: dict[str, Any] | None = None, progress: bool = False,
         announce_ahead_s: float = 0.0) -> PlayResult:
    """Play ``(cmd_t (N,), duty_pct (N, n))`` on an open :class:`bench.valves.ValveController`
    or, for a structure, on several: ``valves`` a sequence of ``(module name,
    controller)`` whose channel blocks are ``duty_pct``'s columns in that order.

    Row ``i`` is sent at lab time ``t_start + cmd_t[i] - cmd_t[0]`` with ``t_start`` =
    now + ``lead_s``. Each sent command is stamped with the midpoint of its exchange,
    written to ``out_dir/commands.csv`` (times from ``t_start``; one file for every
    channel) and handed to ``publish`` (a payload, e.g. a Zenoh put; for several modules a
    mapping module name -> publisher: each module's four duties on its own key); ``hold``
    messages are published when nothing was sent for ``heartbeat_s`` lab seconds. ``stop``
    ends the run early (status ``aborted``). KeyboardInterrupt and SIGTERM (with
    :func:`bench.session.sigterm_raises`) propagate after the valves are closed and the
    files written. Every controller's watchdog is armed and fed while the loop lives; any
    one's lost link ends the run and closes them all. Publishing errors are counted,
    never allowed to stop the closing of the valves.

    ``announce_ahead_s`` > 0 publishes each row that many lab seconds before it is due,
    stamped with when it is due (``t_start + cmd_t[i] - cmd_t[0]``), instead of after the
    switch with the measured stamp (commands.csv keeps the measured stamps): a live
    estimator then has every command before the poses it governs and never re-runs one.
    A run that ends early restates every announced row it did not play as all closed
    (the same stamp: the later message wins), then sends its ``end``.
    """
    clock = clock or LabClock()
    cmd_t = np.asarray(cmd_t, float)
    duty_pct = np.asarray(duty_pct, float)
    out = Path(out_dir) if out_dir is not None else None
    mods = [(body, valves)] if not isinstance(valves, list | tuple) else [tuple(m) for m in valves]
    idents = [v.identify() for _, v in mods]
    widths = [i.n_channels for i in idents]
    cols = np.cumsum([0, *widths])
    check_sequence(cmd_t, duty_pct, int(cols[-1]), mods[0][1].duty_limits)
    for (_, v) in mods[1:]:
        check_sequence(cmd_t, duty_pct, int(cols[-1]), v.duty_limits)
    n_ch = int(cols[-1])
    pubs = ({name: publish for name, _ in mods} if callable(publish) or publish is None
            else dict(publish))
    seq = 0
    pub_errors = 0

    def announce(t: float, duty, kind: str) -> None:
        """One message per module: its block of ``duty`` on its key."""
        nonlocal seq, pub_errors
        for j, (name, _) in enumerate(mods):
            p = pubs.get(name)
            if p is None:
                continue
            seq += 1
            try:
                p(encode_command(name, seq, t, tuple(duty[cols[j]:cols[j + 1]]), kind))
            except Exception:  # the network must never keep the valves open
                pub_errors += 1

    rec = None
    valves_meta = [{"module": name, "url": str(v.url), "model": i.model, "firmware": i.firmware,
                    "n_channels": i.n_channels} for (name, v), i in zip(mods, idents, strict=True)]
    meta_all: dict[str, Any] = run_header(
        "input-play", status="running", body=body if len(mods) == 1 else [m[0] for m in mods],
        valves=valves_meta[0] if len(mods) == 1 else valves_meta,
        time_scale=clock.scale, clock_origin=clock.origin,
        watchdog_ms=watchdog_ms, pwm_hz=pwm_hz, heartbeat_s=heartbeat_s,
        planned_s=float(cmd_t[-1] - cmd_t[0]))
    meta_all.update(meta or {})
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        if (out / "commands.csv").exists():
            raise UserError(f"{out} already holds commands.csv; choose another --out")
        rec = CommandLog(out / "commands.csv", n_ch)
        write_json_atomic(out / "run.json", meta_all)

    status, error = "failed", None
    guards: list = []
    sent: list[tuple[float, tuple[float, ...]]] = []
    n_holds = 0
    max_late = 0.0
    t_start = math.nan
    current = (0.0,) * n_ch
    bar = None
    stamp = _Stamper()
    announced = 0  # rows published ahead (announce_ahead_s > 0)
    played = 0

    def due(i: int) -> float:
        return t_start + (cmd_t[i] - cmd_t[0])

    def announce_ahead(now: float) -> None:
        """Publish the rows due within ``announce_ahead_s`` of ``now``, stamped when due."""
        nonlocal announced, last_msg
        while (announce_ahead_s > 0 and announced < len(cmd_t)
               and due(announced) - announce_ahead_s <= now):
            d = tuple(float(x) for x in duty_pct[announced])
            announce(due(announced), d,
                     "end" if announced == len(cmd_t) - 1 and not any(d) else "set")
            announced += 1
            last_msg = now

    def beat() -> None:
        for g in guards:
            g.heartbeat()
            if g.feed_error is not None:  # one module's lost link ends the run for all
                raise g.feed_error

    try:
        with contextlib.ExitStack() as stack:  # on exit every controller is closed, confirmed
            stack.enter_context(frozen_heap())  # no long GC pause between two commands
            for _, v in mods:
                guards.append(stack.enter_context(v.safe(watchdog_ms)))
            for _, v in mods:
                v.set_freq(pwm_hz)
            t_start = clock.now() + lead_s
            meta_all["t0_lab"] = t_start
            if out is not None:
                write_json_atomic(out / "run.json", meta_all)
            last_msg = clock.now()
            announce(last_msg, current, "hold")
            bar = tqdm(total=round(float(cmd_t[-1] - cmd_t[0]), 1), unit="s", desc="play",
                       file=sys.stderr, disable=not progress,
                       bar_format="{l_bar}{bar}| {n:.0f}/{total:.0f} s [{elapsed}<{remaining}]")
            last = len(cmd_t) - 1
            for i in range(len(cmd_t)):
                target = due(i)
                while True:
                    now = clock.now()
                    if stop is not None and stop.is_set():
                        raise _Stopped()
                    announce_ahead(now)
                    if now >= target:
                        break
                    if now - last_msg >= heartbeat_s:
                        announce(now, current, "hold")
                        n_holds += 1
                        last_msg = now
                    beat()
                    wait = min(target - now, last_msg + heartbeat_s - now)
                    if announced < len(cmd_t) and announce_ahead_s > 0:
                        wait = min(wait, max(due(announced) - announce_ahead_s - now, 0.0))
                    if wait > 4e-4 * clock.scale:
                        time.sleep(min(clock.real_s(wait) - 2e-4, 0.05))
                d = tuple(float(x) for x in duty_pct[i])
                ta = clock.now()
                for j, (_, v) in enumerate(mods):
                    v.set_all(d[cols[j]:cols[j + 1]])
                tb = clock.now()
                t = ta + stamp.half_rtt((tb - ta) / len(mods))
                max_late = max(max_late, ta - target)
                current = d
                played = i + 1
                sent.append((t, d))
                if rec is not None:
                    rec.add(t - t_start, d)
                is_end = i == last and not any(d)
                if announce_ahead_s <= 0:
                    announce(t, d, "end" if is_end else "set")
                    last_msg = t
                beat()
                if progress and bar is not None:
                    bar.update(max(0.0, min(bar.total, cmd_t[i] - cmd_t[0]) - bar.n))
        status = "success"
    except _Stopped:
        status, error = "aborted", "stopped"
    except (KeyboardInterrupt, Terminated, Exception) as exc:
        status, error = ended_by(exc)
        raise
    finally:
        # the safe() contexts have sent OFF and confirmed it (or raised) by now
        t_end = clock.now()
        if bar is not None:
            bar.close()
        for j in range(played, announced):  # announced, never played: closed after all
            announce(due(j), (0.0,) * n_ch, "set")
        if any(current):  # aborted with valves open: the closing row and the end message
            sent.append((t_end, (0.0,) * n_ch))
            if rec is not None and math.isfinite(t_start):
                rec.add(t_end - t_start, (0.0,) * n_ch)
            announce(t_end, (0.0,) * n_ch, "end")
        elif status != "success":
            announce(t_end, (0.0,) * n_ch, "end")
        if rec is not None:
            rec.close()
        finals = [g.final_state for g in guards]
        final = (None if len(guards) < len(mods) or any(f is None for f in finals)
                 else tuple(x for f in finals for x in f))
        meta_all.update({
            "status": status, "error": error,
            "valves_closed_confirmed": final is not None and not any(final),
            "final_state": list(final) if final is not None else None,
            "counts": {"sent": len(sent), "holds": n_holds, "publish_errors": pub_errors,
                       "watchdog_feeds": sum(g.feeds for g in guards)},
            "timing": {"elapsed_lab_s": (t_end - t_start) if math.isfinite(t_start) else None,
                       "max_late_ms": 1e3 * max_late},
        })
        if out is not None:
            with contextlib.suppress(OSError):
                write_json_atomic(out / "run.json", meta_all)
    return PlayResult(status, len(sent), n_holds, t_start, t_end, max_late,
                      final, pub_errors, error, out, sent)


class _Stamper:
    """When did the valves switch? Half the command's round trip after it was sent, but
    never more than the median half round trip of the last 64 commands: a reply that
    comes back late because the host was busy says nothing about when the controller
    acted on the command (it acts on receipt)."""

    def __init__(self) -> None:
        self._recent: list[float] = []

    def half_rtt(self, rtt: float) -> float:
        half = 0.5 * max(rtt, 0.0)
        self._recent.append(half)
        if len(self._recent) > 64:
            del self._recent[0]
        return min(half, float(np.median(self._recent)))


class _Stopped(Exception):
    """``stop`` was set (in-process abort)."""
