"""The use case of ``tpods run play``: plan an input for a module, a vehicle or a structure,
then play it on their valve controllers while publishing every command over Zenoh.

- :func:`plan_play` checks everything before a valve opens (duty limits, the input's
  duties inside them, on/off valves given on/off duties, the structure's controller URLs)
  and makes the command sequence: a :class:`PlayPlan`.
- :func:`play_plan` opens every controller (an ExitStack: each one closed, OFF confirmed,
  on every exit path), declares a command publisher per body on the session it is given,
  waits for a subscriber when asked, and runs :func:`tpods.player.play`.
  KeyboardInterrupt and :class:`bench.session.Terminated` propagate once the valves are
  closed; the caller says so (:func:`tpods.cli.stopping.valves_closed_exit`).

Durations in s, duties in percent, the watchdog in ms. Nothing is printed: ``on_info``
hears the line that says what is about to be played, ``on_warning`` each warning.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from common.constants import DEFAULT_DUTY_LIMITS
from common.errors import UserError

DEFAULT_BODY = "tpods1"


@dataclass
class PlayPlan:
    """What :func:`plan_play` decided: the command rows ``cmd_t (N,)``, ``duty (N, n)``; the
    duty limits ``(low, high)`` in percent; the layout (``structure`` or ``vehicle``, both
    None for one module); the body's name; per module, its controller URL; the run folder
    and the serial transcript's path (None: not written); ``meta`` for run.json."""

    cmd_t: np.ndarray
    duty: np.ndarray
    limits: tuple[float, float]
    body: str
    urls: dict[str, str]
    structure: Any = None
    vehicle: Any = None
    out: Path | None = None
    capture: Path | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def duration_s(self) -> float:
        return float(self.cmd_t[-1] - self.cmd_t[0])


def module_urls(text: str, names: list[str]) -> dict[str, str]:
    """``NAME=URL,NAME=URL`` for a structure: one controller per module, by name."""
    out: dict[str, str] = {}
    for item in text.split(","):
        name, sep, url = item.partition("=")
        if not sep or not name.strip() or not url.strip():
            raise UserError(f"--valves with --structure takes NAME=URL,NAME=URL (one per module: "
                            f"{', '.join(names)}), got {text!r}")
        out[name.strip()] = url.strip()
    missing = [n for n in names if n not in out]
    extra = [n for n in out if n not in names]
    if missing or extra:
        raise UserError(f"--valves names {', '.join(out)}; the structure's modules are "
                        f"{', '.join(names)}")
    return out


def check_play_duties(duty: np.ndarray, lo: float, hi: float, input_name: str,
                      amplitude_pct: float) -> None:
    """Every open duty of the input inside the duty limits, checked before a valve opens
    (the controller would refuse the first bad one in the middle of the run)."""
    opened = duty[duty > 0]
    bad = opened[(opened < lo) | (opened > hi)]
    if duty.size and (duty.min() < 0 or duty.max() > 100):
        bad = duty[(duty < 0) | (duty > 100)]
    if not bad.size:
        return
    span = f"{duty[duty > 0].min():g}..{duty.max():g} %" if opened.size else f"{duty.min():g} %"
    if input_name == "phase-sine":
        a_max = max(min(50.0 - lo, hi - 50.0), 0.0)
        raise UserError(f"--amplitude {amplitude_pct:g} puts the phase-sine duties at "
                        f"{50 - amplitude_pct:g}..{50 + amplitude_pct:g} %, outside --duty-limits "
                        f"{lo:g},{hi:g}: use --amplitude {a_max:g} or less")
    raise UserError(f"--input {input_name}: open duties span {span}, outside --duty-limits "
                    f"{lo:g},{hi:g} (first: {float(bad[0]):g} %)")


def parse_duty_limits(text: str) -> tuple[float, float]:
    """``LOW,HIGH`` (or ``LOW:HIGH``) within 0-100, LOW <= HIGH."""
    from bench.session import parse_duty_steps
    from common.plausible import check_duty_range

    lim = parse_duty_steps(text.replace(":", ","))
    if len(lim) == 2:
        check_duty_range(lim[0], lim[1], f"--duty-limits {text}",
                         f"give --duty-limits {lim[1]:g},{lim[0]:g}")
    if len(lim) != 2 or not 0 < lim[0] <= lim[1] <= 100:
        raise UserError(f"--duty-limits must be LOW,HIGH within 0-100, got {text!r}")
    return float(lim[0]), float(lim[1])


def plan_play(valves: str, *, input_name: str, duration_s: float | None, cmd_rate_hz: float,
              amplitude_pct: float, omega_rad_s: float, structure: Any = None,
              vehicle: Any = None, duty_limits: str | None = None, watchdog_ms: int = 500,
              prefix: str = "tpods", body: str | None = None, out: str | None = None,
              force: bool = False, capture: str | bool | None = None) -> PlayPlan:
    """Check a play's settings and make its commands (module doc). ``structure`` and
    ``vehicle`` are the loaded layouts (at most one); ``duty_limits`` None takes the default
    (a vehicle's duty range); ``capture`` True records the transcript into ``out``, a path
    into that folder."""
    from common.outputs import stream_folder
    from estimator.plant.inputs import make_input

    if duty_limits is None:
        lo, hi = vehicle.duty_range() if vehicle is not None else (None, None)
        duty_limits = DEFAULT_DUTY_LIMITS if vehicle is None else f"{max(lo, 1.0):g},{hi:g}"
    body = body or (vehicle.name if vehicle is not None else DEFAULT_BODY)
    lim = parse_duty_limits(duty_limits)
    if watchdog_ms < 50:
        raise UserError("--watchdog-ms must be at least 50")
    if not prefix.strip("/"):
        raise UserError("--prefix must not be empty")
    if structure is not None:
        if capture is not None:
            raise UserError("--capture is not built for --structure yet (one transcript per "
                            "controller)")
        urls = module_urls(valves, [m.name for m in structure.modules])
        n_channels = structure.n_channels
    else:
        urls = {body: valves}
        n_channels = 4 if vehicle is None else vehicle.n_channels
    cmd_t, duty = make_input(input_name, duration_s, cmd_rate_hz, amplitude_pct, omega_rad_s,
                             n_channels=n_channels)
    if vehicle is not None:
        from common.command_rules import onoff_scale_problem

        problem = onoff_scale_problem(duty, [i for i, t in enumerate(vehicle.thrusters)
                                             if t.table is None and not t.dead])
        if problem is not None:
            raise UserError(f"--input {input_name}: {problem}")
    check_play_duties(duty, lim[0], lim[1], input_name, amplitude_pct)
    if capture is True and out is None:
        raise UserError("--capture without a folder records into --out: give --out RUN_DIR or "
                        "--capture DIR")
    folder = None if out is None else stream_folder(out, force=force, command="tpods run play")
    cap = None
    if capture is not None:
        from bench.capture import capture_folder

        cap_dir = Path(folder) if capture is True else capture_folder(capture, force,
                                                                      "tpods run play")
        cap = cap_dir / "valves.serial.jsonl"
    meta = {"input": input_name, "duration_s": float(cmd_t[-1] - cmd_t[0]),
            "cmd_rate_hz": cmd_rate_hz}
    if structure is not None:
        meta = {"input": input_name, "structure": structure.name,
                "duration_s": meta["duration_s"], "cmd_rate_hz": cmd_rate_hz}
    elif vehicle is not None:
        meta["vehicle"] = vehicle.name
    return PlayPlan(cmd_t, duty, lim, body, urls, structure, vehicle,
                    None if folder is None else Path(folder), cap, meta)


def play_plan(plan: PlayPlan, session: Any, *, clock: Any, prefix: str = "tpods",
              valves_baud: int = 115200, watchdog_ms: int = 500, pwm_hz: float = 10.0,
              heartbeat_s: float = 0.1, announce_ahead_s: float = 0.0, progress: bool = True,
              wait_subscriber_s: float = 0.0,
              on_info: Callable[[str], object] = lambda _line: None,
              on_warning: Callable[[str], object] = lambda _line: None):
    """Play ``plan`` on its controllers (module doc); returns :class:`tpods.player.PlayResult`.
    ``session``: an open Zenoh session; commands go out on ``<prefix>/<body>/cmd``, each
    ``announce_ahead_s`` before it is due when that is above 0 (stamped with when it is due)."""
    import zenoh

    from bench.valves import ValveController
    from common.clock_ping import clock_key, serve_clock
    from common.zenoh_net import wait_matching
    from tpods.player import cmd_key, play

    names = list(plan.urls)
    # commands are small and rare: never dropped inside zenoh (block), sent at once
    pubs = {n: session.declare_publisher(
        cmd_key(n, prefix), encoding=zenoh.Encoding("application/json"), express=True,
        congestion_control=zenoh.CongestionControl.BLOCK) for n in names}
    # the player host's clock, for the estimator's round-trip measurement (common/clock_ping.py)
    clock_q = serve_clock(session, clock_key(plan.body, prefix))
    what = (cmd_key(plan.body, prefix) if plan.structure is None
            else f"{prefix.strip('/')}/<module>/cmd")
    if plan.structure is None and plan.vehicle is not None and plan.out is not None:
        plan.vehicle.write(plan.out)  # the folder of a vehicle run (docs/run-format.md)
    try:
        with contextlib.ExitStack() as stack:
            ctrls = [(n, stack.enter_context(ValveController(
                plan.urls[n], baudrate=valves_baud, duty_limits=plan.limits,
                **({"capture": plan.capture} if plan.structure is None else {}))))
                for n in names]
            if plan.structure is None:
                scale = f" (time scale {clock.scale:g})" if clock.scale != 1 else ""
                on_info(f"play: {plan.meta['input']} for {plan.duration_s:g} s on "
                        f"{plan.urls[plan.body]}, commands on {what}{scale}")
            else:
                on_info(f"play: {plan.meta['input']} for {plan.duration_s:g} s on structure "
                        f"{plan.structure.name!r} "
                        f"({', '.join(f'{n} at {plan.urls[n]}' for n in names)}), "
                        f"commands on {what}")
                if plan.out is not None:
                    plan.structure.write(plan.out)
            if wait_subscriber_s > 0 and not wait_matching(list(pubs.values()), wait_subscriber_s):
                on_warning(f"no subscriber of {what} after {wait_subscriber_s:g} s; playing "
                           "(nothing records the commands over Zenoh)")
            common = dict(clock=clock, out_dir=plan.out, watchdog_ms=watchdog_ms, pwm_hz=pwm_hz,
                          heartbeat_s=heartbeat_s, announce_ahead_s=announce_ahead_s,
                          progress=progress, meta=plan.meta)
            if plan.structure is None:
                return play(ctrls[0][1], plan.cmd_t, plan.duty, publish=pubs[plan.body].put,
                            body=plan.body, **common)
            return play(ctrls, plan.cmd_t, plan.duty,
                        publish={n: p.put for n, p in pubs.items()}, **common)
    finally:
        for p in [*pubs.values(), clock_q]:
            with contextlib.suppress(Exception):
                p.undeclare()
