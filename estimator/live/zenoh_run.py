"""The live estimator on Zenoh: subscribe to a body's poses and commands, publish its estimates.

:func:`run_live` wires a :class:`~estimator.live.core.LiveEstimator` to a session
(``tpods/mocap/<body>/pose``, ``tpods/<body>/cmd`` in; ``tpods/<body>/estimate`` out, the
keys of :func:`keys`) until stopped; :func:`console_line` is its one-line status.
"""

from __future__ import annotations

import contextlib
import gc
import math
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import zenoh

from common.wire import ENCODING, cmd_key, decode_command, decode_pose, estimate_key, pose_key
from common.zenoh_net import direct_callback
from estimator.live.core import LiveEstimator


def keys(body: str, mocap_prefix: str = "tpods/mocap", prefix: str = "tpods",
         modules: tuple[str, ...] | list[str] | None = None) -> dict[str, str]:
    """The pose, command and estimate keys of a body; a structure's (``modules``)
    has one command key per module, ``cmd:<module>`` (``tpods/<module>/cmd``), instead of
    the body's ``cmd``."""
    out = {"pose": pose_key(mocap_prefix, body), "estimate": estimate_key(body, prefix)}
    if modules:
        out.update({f"cmd:{m}": cmd_key(m, prefix) for m in modules})
    else:
        out["cmd"] = cmd_key(body, prefix)
    return out


def command_keys(k: dict[str, str]) -> list[str]:
    """The command keys among :func:`keys`' (one, or one per module of a structure)."""
    return [v for name, v in k.items() if name == "cmd" or name.startswith("cmd:")]


@dataclass
class LiveRun:
    """Outcome of :func:`run_live`."""

    status: str
    summary: dict[str, Any]
    elapsed_s: float
    rates: dict[str, float] = field(default_factory=dict)
    after_end: int = 0
    """Poses stamped after the end's span that ended an ``exit_on_end`` run (not used)."""


END_WAIT_MAX_S = 5.0
"""Host seconds after the player's ``end`` at which ``exit_on_end`` stops in any case."""


def run_live(session, estimator: LiveEstimator, *, stop: threading.Event | None = None,
             duration_s: float | None = None, exit_on_end: bool = False,
             end_grace_s: float = 0.5, end_span_s: float = 1.0,
             mocap_prefix: str = "tpods/mocap", prefix: str = "tpods",
             on_console: Callable[[str], None] | None = None, console_period_s: float = 1.0,
             on_idle: tuple[Callable[[], None], ...] = ()) -> LiveRun:
    """Subscribe, estimate and publish until ``stop``, ``duration_s`` or (with
    ``exit_on_end``) the end of the player's input: once its ``end`` command is in, the
    poses stamped up to ``end_span_s`` (lab time) after it are used and the run ends at the
    first pose stamped later (a mocap that keeps streaming; that pose and any after it are
    not used: ``LiveRun.after_end``), or once nothing has arrived for ``end_grace_s`` of
    host time (a stream that stops: a replay), or at the latest :data:`END_WAIT_MAX_S` host
    seconds after the ``end`` (poses that never reach its lab time: a mocap host's clock
    behind the player's). The poses used do not depend on how late a loaded host delivers
    them (one publisher per key keeps its order).

    Zenoh callbacks only queue the payloads with their arrival time; this thread
    decodes, aligns, filters and publishes, sleeping until the next message or the
    next pose's wait deadline. The objects of the start-up (modules, session, filter)
    are frozen out of the garbage collector while it runs (``gc.freeze``): a collection
    of the oldest generation then scans only what the run made, not the whole program
    (measured: 12-17 ms pauses, once per run, at 1 kHz). ``on_idle`` (the
    recorders' hand-overs: :meth:`estimator.live.recorder_process.RecorderProcess.idle`) run
    after an estimate when no message is waiting, so that their work falls between poses;
    so does an ``ls-ekf`` catch-up (:meth:`LiveEstimator.idle_catch_up`), pose by pose
    until a message arrives.
    """
    stop = stop or threading.Event()
    st = estimator.structure
    k = keys(estimator.body, mocap_prefix, prefix,
             [m.name for m in st.modules] if getattr(st, "modules", None) else None)
    q: queue.SimpleQueue = queue.SimpleQueue()
    now = time.time
    bad: dict[str, int] = {}

    def on_pose(sample) -> None:
        q.put((0, sample.payload.to_bytes(), now()))

    def on_cmd(sample) -> None:
        q.put((1, sample.payload.to_bytes(), now()))

    gc.collect()  # before subscribing: nothing is received during this collection
    gc.freeze()
    # BLOCK as the bridge and the player publish: an estimate (a revised one above all)
    # waits for a full transmit queue rather than being dropped
    pub = session.declare_publisher(k["estimate"], encoding=zenoh.Encoding(ENCODING),
                                    express=True,
                                    congestion_control=zenoh.CongestionControl.BLOCK)

    estimator.publish_bytes = pub.put
    subs = [session.declare_subscriber(k["pose"], direct_callback(on_pose))]
    subs += [session.declare_subscriber(key, direct_callback(on_cmd)) for key in command_keys(k)]
    t_start = time.monotonic()
    t_end = None if duration_s is None else t_start + duration_s
    next_console = t_start + console_period_s
    last_counts = (0, 0)
    rates = {"poses_hz": 0.0, "cmds_hz": 0.0}
    end_host: float | None = None
    last_rx = time.monotonic()
    beyond_end = False
    after_end = 0

    def past_the_end(t: float) -> bool:
        """A pose stamped after the span that ends an ``exit_on_end`` run (not used)."""
        nonlocal beyond_end, after_end
        if exit_on_end and estimator.end_seen_t is not None and t > estimator.end_seen_t + end_span_s:
            beyond_end = True
            after_end += 1
            return True
        return False

    status = "success"
    catching_up = False
    try:
        while not stop.is_set():
            mono = time.monotonic()
            if t_end is not None and mono >= t_end:
                break
            if end_host is None and exit_on_end and estimator.end_seen_t is not None:
                end_host = mono
            if end_host is not None and q.empty() and (
                    beyond_end or mono - max(end_host, last_rx) >= end_grace_s
                    or mono - end_host >= END_WAIT_MAX_S):
                break
            dl = estimator.next_deadline()
            timeout = 0.05 if dl is None else min(0.05, max(0.0, dl - now()))
            if catching_up:  # no sleeping while there is catch-up to do in the idle time
                timeout = 0.0
            try:
                item = q.get(timeout=timeout) if timeout > 0 else q.get_nowait()
            except queue.Empty:
                item = None
            batch = 0
            if item is not None:
                last_rx = time.monotonic()
                qs = q.qsize() + 1
                if qs > estimator.counters.max_queue:
                    estimator.counters.max_queue = qs
            while item is not None:
                kind, payload, arr = item
                if kind == 0:
                    d = decode_pose(payload, bad)
                    if d is None:
                        estimator.counters.malformed += 1
                    elif not past_the_end(d["t"]):
                        estimator.pose(d, arr)
                else:
                    c = decode_command(payload, bad, estimator.config.n_channels)
                    if c is None:
                        estimator.counters.malformed += 1
                    else:
                        estimator.command(c, arr)
                batch += 1
                if batch >= 64:
                    break
                try:
                    item = q.get_nowait()
                except queue.Empty:
                    item = None
            estimator.process(now())
            if q.empty():
                for f in on_idle:
                    f()
                catching_up = estimator.idle_catch_up(lambda: not q.empty())
            if time.monotonic() >= next_console:
                c = estimator.counters
                el = time.monotonic() - next_console + console_period_s
                rates = {"poses_hz": (c.poses_rx - last_counts[0]) / el,
                         "cmds_hz": (c.cmds_rx - last_counts[1]) / el}
                last_counts = (c.poses_rx, c.cmds_rx)
                next_console = time.monotonic() + console_period_s
                if on_console is not None:
                    on_console(console_line(estimator, rates, q.qsize()))
    except (KeyboardInterrupt, Exception):
        status = "aborted"
        raise
    finally:
        for s in subs:
            with contextlib.suppress(Exception):
                s.undeclare()
        # what is still queued was received: use it
        while True:
            try:
                kind, payload, arr = q.get_nowait()
            except queue.Empty:
                break
            with contextlib.suppress(Exception):
                d = (decode_pose(payload, bad) if kind == 0
                     else decode_command(payload, bad, estimator.config.n_channels))
                if d is not None and kind == 0:
                    if not past_the_end(d["t"]):
                        estimator.pose(d, arr)
                elif d is not None:
                    estimator.command(d, arr)
        if status == "success":
            estimator.finish()
        else:
            with contextlib.suppress(Exception):
                estimator.process(math.inf)
        estimator.close_pool()
        gc.unfreeze()
        with contextlib.suppress(Exception):
            pub.undeclare()
        estimator.publish_bytes = None
    if status == "success" and stop.is_set():
        status = "stopped"
    return LiveRun(status, estimator.summary(), time.monotonic() - t_start, rates, after_end)


def console_line(est: LiveEstimator, rates: dict[str, float], backlog: int = 0) -> str:
    """One line of live status: estimates with sigma, input rates, counters."""
    e = est.estimate()
    a = est.aligner.stats
    c = est.counters
    if e is None and est.structure is not None and est.hist_t:
        span = est.hist_t[-1] - est.hist_t[0]
        head = (f"{est.structure.kind} {est.structure.name}: LS window {span:.1f}/{est.config.ls_window_s:g} s "
                f"| {est.phase}")
    elif e is None:
        head = "waiting for poses and commands"
    else:
        t_rel = (est.t_last - est.aligner.first_command_t) if est.aligner.first_command_t else 0.0
        head = (f"t {t_rel:7.2f} s | m {e['mass_kg']:.4f} +/- {e['mass_sigma_kg']:.2g} kg | "
                f"Izz {e['izz_kgm2']:.4e} +/- {e['izz_sigma_kgm2']:.1e} | {est.phase}"
                + (" | DIVERGED" if e["diverged"] else " | INCONSISTENT" if e["inconsistent"] else ""))
    return (f"live: {head} | in {rates.get('poses_hz', 0):.0f} poses/s "
            f"{rates.get('cmds_hz', 0):.0f} cmds/s | used {c.updates} occl {a.occluded} "
            f"dup {a.duplicates} old {a.too_old} late-cmd {a.cmds_late} rewound {a.cmds_rewound} "
            f"timeout {a.released_by_timeout} bad {c.malformed} | backlog {backlog + est.aligner.pending}")
