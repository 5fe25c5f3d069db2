"""A thrust characterisation session on a valve controller and an OHAUS balance: the use
case behind ``tpods bench characterize``, callable from a notebook.

:func:`plan_characterize` checks the options (duty steps in %, times in s, the serial
format like 8N1) and prepares the session folder (and the transcripts' folder);
:func:`run_characterize` opens both devices and runs :func:`bench.session.run_session`,
which writes raw.csv, steps.csv and run.json and closes the valves on every exit path
(SIGTERM and Ctrl-C propagate as :class:`bench.session.Terminated` and KeyboardInterrupt
for the caller to report). Nothing is printed: notes and the report are returned as lines.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from bench.capture import capture_folder
from bench.ohaus.driver import OhausScout
from bench.session import (
    SessionConfig,
    SessionResult,
    parse_duty_steps,
    parse_int_list,
    run_session,
)
from bench.valves import ValveController
from common.errors import UserError, Warnings
from common.outputs import stream_folder

MAX_VALVES = 4
"""Valves of a TPODS module's controller (the session checks the device's own count too)."""

SESSION_FILES = ("raw.csv", "steps.csv", "run.json", "valves.serial.jsonl", "scale.serial.jsonl")


@dataclass
class SessionPlan:
    """A checked session: its ``config``, the folder ``out`` it writes, the folder
    ``capture`` of the serial transcripts (or None) and ``notes`` (said on stderr)."""

    config: SessionConfig
    out: Path
    capture: Path | None
    serial: dict = field(default_factory=dict)
    """The balance's data bits, parity and stop bits (:func:`serial_format`)."""
    notes: list[str] = field(default_factory=list)


def serial_format(text: str) -> dict:
    """``8N1``-style data bits, parity and stop bits as the driver's keyword arguments."""
    t = text.strip().upper()
    if len(t) != 3 or t[0] not in "5678" or t[1] not in "NEOMS" or t[2] not in "12":
        raise UserError(f"serial format must look like 8N1 or 7E1, got {text!r}")
    return {"bytesize": int(t[0]), "parity": t[1], "stopbits": int(t[2])}


def replace_empty_failed_session(out: str | Path | None) -> str | None:
    """A session that failed before its first reading (a device that does not answer, an
    option the controller refuses) holds nothing to keep but its run.json, which says why.
    Re-running into the same folder replaces it without ``force``; returns the note saying so."""
    if not out:
        return None
    out = Path(out)
    try:
        names = {p.name for p in out.iterdir()}
        meta = json.loads((out / "run.json").read_text())
        with (out / "raw.csv").open() as fh:
            has_data = sum(1 for _ in zip(range(2), fh, strict=False)) > 1
    except (OSError, ValueError):
        return None
    if not names <= set(SESSION_FILES) or has_data or not isinstance(meta, dict) \
            or meta.get("status") != "failed":
        return None
    for name in SESSION_FILES:
        (out / name).unlink(missing_ok=True)
    return (f"tpods: replacing {out}: a failed session without readings "
            f"({str(meta.get('error') or '')[:80]})")


def plan_characterize(out: str | Path, *, nozzles: str = "1,2,3,4", duty: str = "10:90:10",
                      dwell: float = 5.0, settle: float = 1.0, zero_settle: float = 2.0,
                      zero_dwell: float = 1.0, zero_every: int = 1, pwm_hz: float = 10.0,
                      nozzle_under_test: int = 1, duty_limits: str = "10,90",
                      watchdog_ms: int = 500, scale_format: str = "8N1",
                      capture: str | Path | bool | None = None, force: bool = False,
                      on_note: Callable[[str], object] | None = None) -> SessionPlan:
    """The session's config from the options of ``tpods bench characterize`` (``nozzles``:
    counts of open valves; ``duty``: START:STOP:STEP or a list, %; ``capture``: True for
    the session folder, a folder, or None) and its folder, checked and prepared.
    ``on_note(line)`` hears a note as it arises (a failed session replaced)."""
    lim = parse_duty_steps(duty_limits.replace(":", ","))
    if len(lim) != 2:
        raise UserError(f"--duty-limits must be LOW,HIGH, got {duty_limits!r}")
    cfg = SessionConfig(
        nozzles=parse_int_list(nozzles, "--nozzles"), duties_pct=parse_duty_steps(duty),
        dwell_s=dwell, settle_s=settle, zero_settle_s=zero_settle, zero_dwell_s=zero_dwell,
        zero_every=zero_every, pwm_hz=pwm_hz, nozzle_under_test=nozzle_under_test,
        duty_limits_pct=(lim[0], lim[1]), watchdog_ms=watchdog_ms)
    if not 1 <= cfg.pwm_hz <= 100:
        raise UserError(f"--pwm-hz must be 1-100, got {cfg.pwm_hz:g}")
    if max(cfg.nozzles) > MAX_VALVES:
        raise UserError(f"--nozzles {nozzles}: a TPODS module has {MAX_VALVES} valves; "
                        f"cannot open {max(cfg.nozzles)} at once")
    fmt = serial_format(scale_format)
    notes = Warnings(on_note, [n for n in (replace_empty_failed_session(out),) if n])
    cap = None if capture in (None, True) else capture_folder(capture, force, "tpods bench characterize")
    folder = stream_folder(out, force=force, command="tpods bench characterize")
    return SessionPlan(cfg, Path(folder), Path(folder) if capture is True else cap, fmt, notes)


def run_characterize(plan: SessionPlan, valves: str, scale: str, *, valves_baud: int = 115200,
                     scale_baud: int = 9600, scale_handshake: str = "none", silence_timeout: float = 2.0,
                     scale_mode: str = "auto", scale_poll_interval: float = 0.1,
                     progress: bool = True) -> SessionResult:
    """Open the valve controller at ``valves`` and the balance at ``scale`` (device paths
    or pyserial URLs) and run the planned session into ``plan.out``."""
    cap = plan.capture
    hs = scale_handshake
    with ValveController(valves, baudrate=valves_baud, duty_limits=plan.config.duty_limits_pct,
                         capture=cap and cap / "valves.serial.jsonl") as v, \
         OhausScout(scale, baudrate=scale_baud, xonxoff=hs == "xonxoff", rtscts=hs == "rtscts",
                    silence_timeout=silence_timeout, acquisition=scale_mode,
                    poll_interval_s=scale_poll_interval,
                    capture=cap and cap / "scale.serial.jsonl", **plan.serial) as s:
        return run_session(v, s, plan.config, plan.out, progress=progress)


def session_lines(res: SessionResult, plan: SessionPlan) -> list[str]:
    """The report of a finished session: steps, readings, time against the plan, files."""
    out = [f"session {res.status}: {len(res.steps)} steps, {res.n_readings} readings, "
           f"{res.n_garbage} garbage line(s) skipped",
           f"time {res.elapsed_s:.1f} s for {res.planned_s:.1f} s planned "
           f"(overhead {res.overhead_pct:+.1f} %)",
           f"wrote {plan.out}/raw.csv, steps.csv, run.json"]
    if plan.capture is not None:
        out.append(f"wrote {plan.capture}/valves.serial.jsonl, scale.serial.jsonl (serial transcripts)")
    return out
