"""The processes of a demo run (``tpods demo``, ``--structure``, ``--vehicle``): the private
Zenoh network and the arguments its children get, the ``tpods`` executable, waiting for the
live estimator to listen, playing with a progress bar in lab time, reading the live
estimator's summary line, stopping a child (and the whole run: :func:`stop_run`), and the
valve-switch lag of a run (the emulation's timing: how late the emulated valves applied the
player's commands; :func:`run_outcome`).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from common.errors import UserError
from common.zenoh_net import open_session

SWITCH_LAG_WARN_MS = 1.0
"""Mean valve-switch lag (lab ms) above which a run's physics no longer match its recorded
commands well enough to judge the estimators (tests/support/lab.switch_lag_ms, docs/live.md)."""

STRUCTURE_LAG_WARN_MS = 5.0
"""The same for a structure: the player writes the modules' controllers one after the other,
so module 2's valves switch a median 1.2 lab ms after module 1's by design (docs/live.md);
tests/tpods/test_demo_structure.py judges no estimator above 5 ms."""


def demo_session(args: argparse.Namespace):
    """The demo's Zenoh session and the endpoint its children connect to: a private
    loopback network (two demos on one machine do not mix) unless the Zenoh options say
    otherwise (then ``ep`` is None)."""
    if args.connect or args.listen or args.zenoh_config:
        return open_session(args), None
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        ep = f"tcp/127.0.0.1:{s.getsockname()[1]}"
    return open_session(listen=[ep], no_multicast=True), ep


def child_zenoh_args(args: argparse.Namespace, ep: str | None) -> list[str]:
    """The Zenoh options of a child process: the private endpoint, or the demo's own options."""
    if ep is not None:
        return ["--connect", ep, "--no-multicast"]
    out: list[str] = []
    for e in args.connect or []:
        out += ["--connect", e]
    if args.no_multicast:
        out.append("--no-multicast")
    if args.zenoh_config:
        out += ["--zenoh-config", args.zenoh_config]
    if args.zenoh_mode:
        out += ["--zenoh-mode", args.zenoh_mode]
    return out


def tpods_exe() -> list[str]:
    """The ``tpods`` command beside this Python (or ``python -m tpods.cli``)."""
    exe = Path(sys.executable).with_name("tpods")
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "tpods.cli"]


def wait_subscribed(session, key: str, proc: subprocess.Popen | None, what: str, log: Path,
                    timeout_s: float = 60.0) -> None:
    """Until a subscriber matches ``key`` (the live estimator listens); UserError when
    ``proc`` ends or ``timeout_s`` passes first."""
    probe = session.declare_publisher(key)
    try:
        t0 = time.monotonic()
        while not getattr(probe.matching_status, "matching", False):
            if (proc is not None and proc.poll() is not None) or time.monotonic() - t0 > timeout_s:
                raise UserError(f"{what} did not start (see {log})")
            time.sleep(0.05)
    finally:
        probe.undeclare()


def follow_player(play: subprocess.Popen, duration_s: float, time_scale: float, desc: str,
                  stop_if: Callable[[], bool] | None = None) -> float:
    """A progress bar in lab time until the player ends (or ``stop_if()`` says so); returns
    the wall time it played, s."""
    t_real0 = time.monotonic()
    with tqdm(total=round(duration_s), desc=desc, file=sys.stderr, mininterval=1.0,
              bar_format="{l_bar}{bar}| {n:.0f}/{total:.0f} s [{elapsed}<{remaining}]") as bar:
        while play.poll() is None:
            with contextlib.suppress(subprocess.TimeoutExpired):
                play.wait(0.25)  # returns as soon as the player ends
            el = (time.monotonic() - t_real0) * time_scale
            bar.update(max(0, min(duration_s, el) - bar.n))
            if stop_if is not None and stop_if():
                break
    return time.monotonic() - t_real0


def wait_recorded(run_dir: Path, live: subprocess.Popen, timeout_s: float = 60.0) -> bool:
    """Until the live estimator has sealed its recording in ``run_dir`` (run.json's
    ``data_complete``: poses and commands whole, its final fit still running;
    :meth:`estimator.live.recorder.LiveRecorder.seal`): True; False when it ended first
    or ``timeout_s`` passed (then :func:`live_summary` says how it ended)."""
    meta = run_dir / "run.json"
    t0 = time.monotonic()
    while live.poll() is None and time.monotonic() - t0 < timeout_s:
        try:
            if json.loads(meta.read_text()).get("data_complete") is True:
                return True
        except (OSError, ValueError):  # not written yet (it is replaced atomically)
            pass
        time.sleep(0.01)
    return False


def live_summary(live: subprocess.Popen, log: Path) -> dict[str, Any]:
    """The live estimator's JSON summary (its last stdout line) once it exits after the
    player's end (SIGTERM after 60 s); UserError when it failed."""
    try:
        stdout, _ = live.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        live.send_signal(signal.SIGTERM)
        stdout, _ = live.communicate(timeout=30)
    if live.returncode != 0 or not stdout.strip():
        raise UserError(f"the live estimator failed (see {log})")
    return json.loads(stdout.strip().splitlines()[-1])


def child_failed(what: str, proc: subprocess.Popen, log: Path) -> UserError:
    """The one-line error for a child that exited non-zero: its exit code, the last line of
    its log that names an error (what the child said, so a loaded CI run's failure can be
    read from the test output alone), and the log's path."""
    said = ""
    try:
        lines = [ln.strip() for ln in log.read_text(errors="replace").splitlines() if ln.strip()]
        errs = [ln for ln in lines if "error" in ln.lower()]
        said = (errs or lines or [""])[-1][:300]
    except OSError:
        pass
    return UserError(f"the {what} failed (exit {proc.returncode}"
                     + (f": {said}" if said else "") + f"; see {log})")


def stop(proc: subprocess.Popen, sig: int = signal.SIGTERM, timeout_s: float = 15.0) -> None:
    """Signal a running child and wait for it (killed after ``timeout_s``)."""
    if proc.poll() is None:
        proc.send_signal(sig)
        try:
            proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)


def switch_lag_ms(switches, play_dir: Path, warn_ms: float = SWITCH_LAG_WARN_MS
                  ) -> dict[str, float | int]:
    """How late the emulated valves applied the player's commands: for every valve change
    ``(t_lab, duties)`` in ``switches``, the gap to the player's stamp of the nearest command
    with the same duties (``play_dir``'s commands.csv and run.json), lab ms:
    ``{"mean", "p99", "max", "n", "warn_ms"}`` (a mean above ``warn_ms`` misplaces enough
    impulse to bias the estimates: :data:`SWITCH_LAG_WARN_MS` for one module,
    :data:`STRUCTURE_LAG_WARN_MS` for a structure)."""
    meta = json.loads((play_dir / "run.json").read_text())
    cmd = np.loadtxt(play_dir / "commands.csv", delimiter=",", skiprows=1, ndmin=2)
    t_cmd, duties = cmd[:, 0] + float(meta["t0_lab"]), cmd[:, 1:]
    sw_t = np.array([float(t) for t, _ in switches])
    sw_d = np.array([np.asarray(d, float) for _, d in switches]).reshape(len(sw_t), -1)
    lags = np.full(len(sw_t), np.nan)
    if len(sw_t) and len(t_cmd):
        # the two commands around a change are the nearest of all: where one of them has
        # its duties, that is the gap (nearly every change); the rest are searched in full
        i = np.clip(np.searchsorted(t_cmd, sw_t), 1, len(t_cmd) - 1) if len(t_cmd) > 1 \
            else np.zeros(len(sw_t), int)
        for j in (i - 1, i):
            hit = np.all(np.isclose(duties[j], sw_d), axis=1)
            lags = np.where(hit, np.fmin(lags, np.abs(t_cmd[j] - sw_t)), lags)
        _nearest_same_duties(t_cmd, duties, sw_t, sw_d, np.nonzero(np.isnan(lags))[0], lags)
    lags = lags[~np.isnan(lags)].tolist()
    if not lags:
        return {"mean": 0.0, "p99": 0.0, "max": 0.0, "n": 0, "warn_ms": warn_ms}
    ms = 1e3 * np.asarray(lags)
    return {"mean": float(ms.mean()), "p99": float(np.percentile(ms, 99)), "max": float(ms.max()),
            "n": int(ms.size), "warn_ms": warn_ms}


def _nearest_same_duties(t_cmd: np.ndarray, duties: np.ndarray, sw_t: np.ndarray,
                         sw_d: np.ndarray, ks: np.ndarray, lags: np.ndarray) -> None:
    """For each change ``k`` in ``ks``: ``lags[k]`` = the gap to the nearest command whose
    duties are ``np.isclose`` to its own (left NaN when none is). The same comparison as a
    search of every command, on the few whose first duty can pass it (commands sorted by
    first duty, a window of twice isclose's tolerance): a long run's switches that miss
    their neighbours (the valves' rounding) cost milliseconds, not a second."""
    order = np.argsort(duties[:, 0], kind="stable")
    first = duties[order, 0]
    for k in ks:
        b = sw_d[k]
        tol = 2.0 * (1e-8 + 1e-5 * abs(float(b[0])))  # np.isclose's atol + rtol |b|, doubled
        lo = int(np.searchsorted(first, b[0] - tol, side="left"))
        hi = int(np.searchsorted(first, b[0] + tol, side="right"))
        cand = order[lo:hi]
        same = np.all(np.isclose(duties[cand], b), axis=1)
        if same.any():
            lags[k] = np.min(np.abs(t_cmd[cand[same]] - sw_t[k]))


def lag_text(lag: dict[str, Any] | None) -> str:
    """What the run's valve-switch lag says (the emulation's timing on this machine)."""
    if not lag:
        return ""
    verdict = ("the physics matched the recorded commands" if lag["mean"] <= lag["warn_ms"]
               else "MORE than the machine can take at this time scale: the physics do not match "
                    "the recorded commands and the estimates carry that bias")
    return (f"The emulated valves switched {lag['mean']:.2f} lab ms after the player's stamps on "
            f"average (p99 {lag['p99']:.1f} ms, {lag['n']} valve changes): {verdict}.")


def lab_time_text(duration_s: float, time_scale: float) -> str:
    """``"120 s of lab time at time scale 2 (60 s real)"``."""
    return (f"{duration_s:g} s of lab time at time scale {time_scale:g} "
            f"({duration_s / time_scale:.0f} s real)")


def print_run_timing(name: str, lag: dict[str, float | int], phases: dict[str, float],
                     time_scale: float) -> None:
    """The run's valve-switch lag and the wall time of its phases; a warning on stderr when
    the lag says the machine could not keep up with the time scale."""
    print(f"   emulated valves switched {lag['mean']:.2f} lab ms after the player's stamps on "
          f"average (p99 {lag['p99']:.1f} ms, {lag['n']} changes); wall time: "
          + ", ".join(f"{k} {v:.1f} s" for k, v in phases.items()))
    if lag["mean"] > lag["warn_ms"]:
        print(f"tpods: warning: the machine is too loaded for time scale {time_scale:g}: the "
              f"emulated valves switched {lag['mean']:.1f} lab ms late on average (more than "
              f"{lag['warn_ms']:g} ms): the {name}'s physics do not match its recorded "
              "commands and its estimates carry that bias", file=sys.stderr)


def finish_play(procs: dict[str, subprocess.Popen], d: Path, duration_s: float,
                time_scale: float, desc: str, closed: str) -> float:
    """Follow the ``play`` child in lab time until it ends (or the ``plant`` dies: the
    player is stopped, ``closed`` says which valves it closed); UserError when the plant
    stopped or the player failed (their logs in ``d``). Returns the wall time played, s."""
    played = follow_player(procs["play"], duration_s, time_scale, desc,
                           stop_if=lambda: procs["plant"].poll() is not None)
    if procs["play"].poll() is None:  # the plant died under the player
        stop(procs["play"], signal.SIGINT)
        raise UserError(f"the simulated plant stopped during the run (see {d / 'plant.log'}); "
                        f"the player closed {closed}")
    if procs["play"].returncode != 0:
        raise child_failed("player", procs["play"], d / "play.log")
    return played


def stop_run(procs: dict[str, subprocess.Popen], logs: dict[str, Any], session) -> None:
    """The end of a demo run on every path: the player first (SIGINT: it closes the valves
    and confirms OFF), then the estimator, the plant (its ptys) last; the logs, the session."""
    for name in ("play", "live", "plant"):
        if name in procs:
            stop(procs[name], signal.SIGINT if name == "play" else signal.SIGTERM)
    for fh in logs.values():
        fh.close()
    session.close()


def run_outcome(d: Path, warn_ms: float = SWITCH_LAG_WARN_MS) -> dict[str, Any]:
    """After the plant wrote its truth: the player's status (``play``) and the valve-switch
    lag (``switch_lag_ms``) of the run in ``d``."""
    play_meta = json.loads((d / "play" / "run.json").read_text())
    sw = np.loadtxt(d / "plant" / "switches.csv", delimiter=",", skiprows=1, ndmin=2)
    return {"play": {k: play_meta.get(k) for k in ("status", "valves_closed_confirmed", "counts",
                                                   "timing")},
            "switch_lag_ms": switch_lag_ms([(r[0], r[1:]) for r in sw], d / "play", warn_ms)}
