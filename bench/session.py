"""Thrust characterisation session: duty steps on the valves, thrust from the balance.

For each nozzle count ``k`` and duty step: open the nozzle under test and ``k - 1``
others at that duty, discard ``settle_s``, record every reading for ``dwell_s``,
close. Between steps (every ``zero_every`` steps) the zero is measured with the
valves closed (``zero_settle_s`` discarded, ``zero_dwell_s`` recorded) and the
drift is removed by linear interpolation between the zeros around each step.

Output folder:

- ``raw.csv``: every reading as it arrives (appended and flushed per line):
  ``t_s,window,phase,step,n_open,duty_pct,reading_gf,stable``; ``phase`` is
  ``check``, ``zero_settle``, ``zero``, ``settle`` or ``dwell``.
- ``steps.csv``: per step ``step,n_open,duty_pct,t_start_s,t_end_s,n,n_unstable,
  mean_raw_gf,zero_before_gf,zero_after_gf,drift_gf,thrust_gf,std_gf,sem_gf``.
- ``run.json``: configuration, device identities (``devices.scale.acquisition``: the
  balance's requested and used acquisition mode, continuous print or ``IP`` polling,
  the fallback reason and the poll rate), ``t0_unix`` (wall-clock time of
  ``t_s = 0``), timing, counts, exit status
  (``running`` while it runs, then ``success`` / ``aborted`` / ``failed``: anything but
  ``success`` is a partial session, see docs/run-format.md) and whether OFF was confirmed.

Choose ``settle_s`` and ``zero_settle_s`` of at least five time constants of the
balance's response (about 0.3 s for a Scout): the residual of the step response
biases each mean by roughly ``lag / dwell * exp(-settle / lag)`` of the step.

The pure parts (``plan_steps``, ``summarize_steps``) work on plain arrays and frames.
"""

from __future__ import annotations

import contextlib
import math
import signal
import sys
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from tqdm import tqdm

from bench import clock
from bench.ohaus.driver import OhausScout, Reading
from bench.valves import ValveController
from common.errors import DeviceError, UserError
from common.plausible import check_duty_range
from common.runfolder import warn_if_partial
from common.runwriter import CsvLog, run_header, write_json_atomic
from common.thrust_table import GF_TO_N

if TYPE_CHECKING:  # pandas is imported where a frame is made: `tpods run play` and the live
    import pandas as pd  # estimator import this module for its signals, not for its frames

RAW_COLUMNS = ["t_s", "window", "phase", "step", "n_open", "duty_pct", "reading_gf", "stable"]
STEP_COLUMNS = ["step", "n_open", "duty_pct", "t_start_s", "t_end_s", "n", "n_unstable",
                "mean_raw_gf", "zero_before_gf", "zero_after_gf", "drift_gf", "thrust_gf",
                "std_gf", "sem_gf"]


class Terminated(BaseException):
    """SIGTERM received (raised in the main thread by :func:`sigterm_raises`)."""


def ended_by(exc: BaseException) -> tuple[str, str]:
    """The (status, error) that run.json records for a valve run ended by ``exc``:
    "aborted" on SIGTERM or Ctrl-C, "failed" on any other error."""
    if isinstance(exc, KeyboardInterrupt | Terminated):
        return "aborted", str(exc) or "interrupted (Ctrl-C)"
    return "failed", str(exc) or exc.__class__.__name__


@contextlib.contextmanager
def sigterm_raises() -> Iterator[None]:
    """Within the block SIGTERM raises :class:`Terminated` and SIGINT raises
    KeyboardInterrupt, so ``finally`` clauses (closing the valves) run.

    SIGINT is set explicitly because a process started in the background by a
    non-interactive shell inherits SIGINT ignored, and Ctrl-C must still stop a session.
    """

    def handler(signum, frame):
        raise Terminated("terminated (SIGTERM)")

    try:
        old_term = signal.signal(signal.SIGTERM, handler)
        old_int = signal.signal(signal.SIGINT, signal.default_int_handler)
    except ValueError:  # not the main thread: leave signals alone
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old_term)
        signal.signal(signal.SIGINT, old_int)


@dataclass(frozen=True)
class SessionConfig:
    """Settings of a characterisation session (durations in seconds, duties in percent)."""

    nozzles: tuple[int, ...] = (1, 2, 3, 4)
    duties_pct: tuple[float, ...] = (10, 20, 30, 40, 50, 60, 70, 80, 90)
    dwell_s: float = 5.0
    settle_s: float = 1.0
    zero_settle_s: float = 2.0
    zero_dwell_s: float = 1.0
    zero_every: int = 1
    pwm_hz: float = 10.0
    nozzle_under_test: int = 1
    duty_limits_pct: tuple[float, float] = (10.0, 90.0)
    watchdog_ms: int = 500

    def __post_init__(self) -> None:
        lo, hi = self.duty_limits_pct
        check_duty_range(lo, hi, "duty limits (--duty-limits LOW,HIGH)", f"give {hi:g},{lo:g}")
        if not 0 < lo <= hi <= 100:
            raise UserError(f"duty limits must satisfy 0 < low <= high <= 100, got {lo:g}-{hi:g}")
        if not self.nozzles or any(k < 1 for k in self.nozzles):
            raise UserError("nozzle counts must be positive integers")
        if not self.duties_pct:
            raise UserError("no duty steps")
        bad = [d for d in self.duties_pct if not lo <= d <= hi]
        if bad:
            raise UserError(f"duty {bad[0]:g} % is outside the allowed {lo:g}-{hi:g} % "
                            f"(change the duty limits to allow it)")
        for name in ("dwell_s", "settle_s", "zero_settle_s", "zero_dwell_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise UserError(f"{name} must be a non-negative number of seconds")
        if self.dwell_s <= 0 or self.zero_dwell_s <= 0:
            raise UserError("dwell and zero dwell must be positive")
        if self.zero_every < 1:
            raise UserError("zero_every must be at least 1")
        if self.watchdog_ms < 50:
            raise UserError("the watchdog must be at least 50 ms")

    @property
    def planned_s(self) -> float:
        """Planned time: every settle + dwell window, zeros included, seconds."""
        n_steps = len(self.nozzles) * len(self.duties_pct)
        n_zero = 1 + math.ceil(n_steps / self.zero_every)
        return n_steps * (self.settle_s + self.dwell_s) + n_zero * (self.zero_settle_s + self.zero_dwell_s)


@dataclass(frozen=True)
class Step:
    """One duty step: ``duties`` per channel (percent), ``n_open`` valves open."""

    index: int
    n_open: int
    duty_pct: float
    duties: tuple[float, ...]


def open_channels(n_open: int, nozzle_under_test: int, n_channels: int) -> list[int]:
    """Channels (1-based) to open: the nozzle under test first, then the lowest others."""
    others = [c for c in range(1, n_channels + 1) if c != nozzle_under_test]
    return [nozzle_under_test] + others[: n_open - 1]


def plan_steps(config: SessionConfig, n_channels: int) -> list[Step]:
    """The session's duty steps in order (nozzle count outer, duty inner)."""
    if not 1 <= config.nozzle_under_test <= n_channels:
        raise UserError(f"nozzle under test must be 1-{n_channels}, got {config.nozzle_under_test}")
    if max(config.nozzles) > n_channels:
        raise UserError(f"the controller has {n_channels} valves; cannot open {max(config.nozzles)}")
    steps = []
    for k in config.nozzles:
        chans = open_channels(k, config.nozzle_under_test, n_channels)
        for d in config.duties_pct:
            duties = tuple(float(d) if c in chans else 0.0 for c in range(1, n_channels + 1))
            steps.append(Step(len(steps), k, float(d), duties))
    return steps


def reading_to_gf(r: Reading) -> float | None:
    """Balance reading as gram-force (grams on the pan); None for a unit that is not a force/mass."""
    if r.unit == "N":
        return r.value / GF_TO_N
    return r.grams


def summarize_steps(raw: pd.DataFrame) -> pd.DataFrame:
    """Per-step statistics from raw readings (columns RAW_COLUMNS), drift-corrected.

    The zero of each ``zero`` window is its mean reading at its mean time; the zero
    at each dwell reading is interpolated linearly in time between the windows
    (held constant beyond the first/last). Returns a frame with STEP_COLUMNS.
    """
    import pandas as pd

    zeros = raw[raw["phase"] == "zero"].groupby("window").agg(t=("t_s", "mean"), z=("reading_gf", "mean"))
    zt, zv = zeros["t"].to_numpy(), zeros["z"].to_numpy()
    rows = []
    for step, g in raw[raw["phase"] == "dwell"].groupby("step", sort=True):
        t = g["t_s"].to_numpy()
        y = g["reading_gf"].to_numpy()
        if len(zt):
            z = np.interp(t, zt, zv)
            before = zv[zt < t[0]]
            after = zv[zt > t[-1]]
            zb = float(before[-1]) if len(before) else math.nan
            za = float(after[0]) if len(after) else math.nan
        else:
            z = np.zeros_like(y)
            zb = za = math.nan
        corr = y - z
        n = len(y)
        std = float(np.std(corr, ddof=1)) if n > 1 else math.nan
        rows.append({
            "step": int(step), "n_open": int(g["n_open"].iloc[0]), "duty_pct": float(g["duty_pct"].iloc[0]),
            "t_start_s": float(t[0]), "t_end_s": float(t[-1]), "n": n,
            "n_unstable": int((g["stable"] == 0).sum()), "mean_raw_gf": float(np.mean(y)),
            "zero_before_gf": zb, "zero_after_gf": za, "drift_gf": float(np.mean(z)),
            "thrust_gf": float(np.mean(corr)), "std_gf": std,
            "sem_gf": std / math.sqrt(n) if n > 1 else math.nan,
        })
    return pd.DataFrame(rows, columns=STEP_COLUMNS)


@dataclass
class SessionResult:
    """What a session did: status, output folder, timing (s), counts."""

    status: str
    out_dir: Path
    planned_s: float
    elapsed_s: float
    n_readings: int
    n_garbage: int
    error: str | None = None
    steps: pd.DataFrame = field(default_factory=lambda: _frame([], STEP_COLUMNS))

    @property
    def overhead_pct(self) -> float:
        return 100.0 * (self.elapsed_s - self.planned_s) / self.planned_s


def _frame(rows: list, columns) -> pd.DataFrame:
    import pandas as pd

    return pd.DataFrame(rows, columns=columns)


class _Recorder:
    """Appends readings to raw.csv (a :class:`common.runwriter.CsvLog`), flushing every line."""

    # t_s to 0.1 ms, duty as %g, the reading in grams at full precision (shortest repr)
    FORMATS = ("%.4f", str, str, str, str, "%g", repr, str)

    def __init__(self, path: Path, t0: float) -> None:
        self.log = CsvLog(path, RAW_COLUMNS, self.FORMATS)
        self.t0 = t0
        self.rows: list[tuple] = []
        self.n_other_unit = 0

    def add(self, r: Reading, window: int, phase: str, step: int, n_open: int, duty: float) -> None:
        gf = reading_to_gf(r)
        if gf is None:
            self.n_other_unit += 1
            return
        row = (r.t - self.t0, window, phase, step, n_open, duty, gf, int(r.stable))
        self.rows.append(row)
        self.log.write(*row)

    def frame(self) -> pd.DataFrame:
        return _frame(self.rows, RAW_COLUMNS)

    def close(self) -> None:
        self.log.close()


def run_session(valves: ValveController, scale: OhausScout, config: SessionConfig,
                out_dir: str | Path, progress: bool = True) -> SessionResult:
    """Run a characterisation session on open devices; write raw.csv, steps.csv, run.json.

    The valves are closed (OFF confirmed by STATE?) on every exit path; the
    controller watchdog is armed and fed only while this loop is alive. Exceptions
    (including KeyboardInterrupt and :class:`Terminated`) propagate after the
    output is written with status ``failed`` / ``aborted``.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t_start = clock.monotonic()
    meta: dict[str, Any] = run_header("thrust-characterisation", status="running",
                                      t0_unix=time.time(), config=asdict(config), devices={})
    write_json_atomic(out / "run.json", meta)

    rec = _Recorder(out / "raw.csv", t_start)
    status, error = "failed", None
    guard = None
    window = 0
    bar = None
    t_loop = math.nan
    try:
        # ---- check both devices before anything can open
        ident = valves.identify()
        meta["devices"]["valves"] = {"url": str(valves.url), "model": ident.model,
                                     "firmware": ident.firmware, "n_channels": ident.n_channels}
        steps = plan_steps(config, ident.n_channels)
        valves.off()
        with contextlib.suppress(DeviceError):  # PU: the unit of lines printed without one
            scale.unit()
        # a balance that prints only tare/total lines fails here with NotALoadReading
        check = scale.read("IP")
        if reading_to_gf(check) is None:
            raise DeviceError(f"the balance reads in {check.unit!r}; set it to grams (g)")
        meta["devices"]["scale"] = {"url": str(scale.url), "version": scale.version(),
                                    "unit": check.unit, "unit_verified": scale.verified_unit,
                                    "legend": check.legend, "settings": scale.settings}
        write_json_atomic(out / "run.json", meta)
        rec.add(check, -1, "check", -1, 0, 0.0)
        bar = tqdm(total=round(config.planned_s, 1), unit="s", desc="characterise", file=sys.stderr,
                   disable=not progress,
                   bar_format="{l_bar}{bar}| {n:.0f}/{total:.0f} s [{elapsed}<{remaining}]{postfix}")
        scale.zero()
        with valves.safe(config.watchdog_ms) as guard:
            valves.set_freq(config.pwm_hz)
            scale.start_continuous()
            meta["devices"]["scale"]["acquisition"] = scale.acquisition_info()
            write_json_atomic(out / "run.json", meta)
            if scale.fallback_message:
                tqdm.write(scale.fallback_message, file=sys.stderr)
            t_loop = clock.monotonic()
            planned_done = 0.0

            def last_event() -> float:
                """When the host last heard from a device (the reply to the last command,
                the last bytes from the balance): windows start there, so a replayed
                session (bench.protocol_replay) cuts them at the recorded times."""
                ts = [t for t in (valves.last_caller_t, scale.link.line_t) if math.isfinite(t)]
                return max(ts) if ts else clock.monotonic()

            def record(duration: float, phase: str, step: int, n_open: int, duty: float,
                       after: str | None = None, start: float | None = None) -> float:
                if after is not None:
                    # lines printed during the previous phase but still waiting in the
                    # host's buffers belong to that phase, not to this window
                    for r in scale.received():
                        rec.add(r, window, after, step, n_open, duty)
                end = (last_event() if start is None else start) + duration
                while True:
                    r = scale.next_reading(end)
                    guard.heartbeat()
                    if r is None:
                        break
                    rec.add(r, window, phase, step, n_open, duty)
                    if progress:
                        done = planned_done + duration - max(0.0, end - clock.monotonic())
                        bar.update(max(0.0, min(bar.total, done) - bar.n))
                return end

            def zero_window() -> None:
                nonlocal window, planned_done
                end = record(config.zero_settle_s, "zero_settle", -1, 0, 0.0)
                record(config.zero_dwell_s, "zero", -1, 0, 0.0, after="zero_settle", start=end)
                planned_done += config.zero_settle_s + config.zero_dwell_s
                window += 1

            zero_window()
            for st in steps:
                bar.set_postfix_str(f"{st.n_open} nozzle(s) at {st.duty_pct:g} %", refresh=False)
                valves.set_all(st.duties)
                end = record(config.settle_s, "settle", st.index, st.n_open, st.duty_pct)
                record(config.dwell_s, "dwell", st.index, st.n_open, st.duty_pct, after="settle", start=end)
                valves.off()
                planned_done += config.settle_s + config.dwell_s
                window += 1
                if (st.index + 1) % config.zero_every == 0 or st.index == len(steps) - 1:
                    zero_window()
                if guard.feed_error is not None:
                    raise guard.feed_error
        status = "success"
    except (KeyboardInterrupt, Terminated, Exception) as exc:
        status, error = ended_by(exc)
        raise
    finally:
        if bar is not None:
            bar.close()
        t_end = clock.monotonic()
        rec.close()
        with contextlib.suppress(Exception):
            if scale.acquiring:
                scale.stop_continuous()
        table = summarize_steps(rec.frame())
        table.to_csv(out / "steps.csv", index=False)
        closed = guard is not None and guard.final_state is not None and not any(guard.final_state)
        loop_s = t_end - t_loop if math.isfinite(t_loop) else math.nan
        if "scale" in meta["devices"] and scale.mode_in_use is not None:
            n_loop = sum(1 for row in rec.rows if row[1] >= 0)
            meta["devices"]["scale"]["acquisition"] = scale.acquisition_info() | {
                "achieved_rate_hz": round(n_loop / loop_s, 2) if loop_s > 0 else None}
        meta.update({
            "status": status, "error": error,
            "valves_closed_confirmed": closed if guard is not None else None,
            "final_state": list(guard.final_state) if guard and guard.final_state is not None else None,
            "timing": {"planned_s": config.planned_s, "elapsed_s": t_end - t_start,
                       "setup_s": (t_loop - t_start) if math.isfinite(t_loop) else None,
                       "loop_s": loop_s,
                       "overhead_pct": 100.0 * (t_end - t_start - config.planned_s) / config.planned_s,
                       "loop_overhead_pct": 100.0 * (loop_s - config.planned_s) / config.planned_s},
            "counts": {"readings": len(rec.rows), "garbage_lines": scale.n_garbage,
                       "garbage_examples": [repr(g) for g in scale.garbage_examples],
                       "other_unit_readings": rec.n_other_unit,
                       "skipped_legend_lines": scale.n_skipped_legend,
                       "skipped_legend_examples": [repr(g) for g in scale.skipped_examples],
                       "steps_done": len(table),
                       "watchdog_feeds": guard.feeds if guard is not None else 0},
        })
        write_json_atomic(out / "run.json", meta)
    return SessionResult(status, out, config.planned_s, t_end - t_start, len(rec.rows),
                         scale.n_garbage, error, table)


def parse_duty_steps(text: str) -> tuple[float, ...]:
    """``"10:90:10"`` (start:stop:step, inclusive) or ``"10,20,50"`` -> duties in percent."""
    try:
        if ":" in text:
            parts = [float(x) for x in text.split(":")]
            if len(parts) == 3 and parts[2] > 0:
                check_duty_range(parts[0], parts[1], f"duty steps {text!r} (START:STOP:STEP)",
                                 f"give {parts[1]:g}:{parts[0]:g}:{parts[2]:g}")
            if len(parts) != 3 or parts[2] <= 0 or parts[1] < parts[0]:
                raise ValueError
            n = int(math.floor((parts[1] - parts[0]) / parts[2] + 1e-9)) + 1
            vals = tuple(round(parts[0] + i * parts[2], 9) for i in range(n))
        else:
            vals = tuple(float(x) for x in text.split(",") if x.strip())
        if not vals or not all(math.isfinite(v) for v in vals):
            raise ValueError
    except ValueError:
        raise UserError(f"duty steps must be START:STOP:STEP or a comma list, got {text!r}") from None
    return vals


def parse_int_list(text: str, what: str) -> tuple[int, ...]:
    try:
        vals = tuple(int(x) for x in text.split(",") if x.strip())
        if not vals:
            raise ValueError
    except ValueError:
        raise UserError(f"{what} must be comma-separated integers, got {text!r}") from None
    return vals


def read_session(run_dir: str | Path) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Read a session folder: ``(raw, steps)``; steps are recomputed from raw.csv when
    steps.csv is missing or empty (a session killed before it could write it). A session
    whose run.json status is not ``success`` (``running``: killed; ``aborted``, ``failed``)
    is partial: read, with one warning line on stderr
    (:func:`common.runfolder.warn_if_partial`)."""
    import pandas as pd

    run = Path(run_dir)
    if not run.is_dir():
        raise UserError(f"{run}: no such run folder")
    raw_path = run / "raw.csv"
    try:
        raw = pd.read_csv(raw_path)
    except FileNotFoundError:
        raise UserError(f"{raw_path}: not found (is this a characterisation run?)") from None
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise UserError(f"{raw_path}: unreadable ({exc})") from None
    missing = set(RAW_COLUMNS) - set(raw.columns)
    if missing:
        raise UserError(f"{raw_path}: missing column(s) {', '.join(sorted(missing))}")
    try:
        raw = raw.astype({"t_s": float, "reading_gf": float, "duty_pct": float, "step": int,
                          "n_open": int, "window": int, "stable": int})
    except (ValueError, TypeError) as exc:
        raise UserError(f"{raw_path}: non-numeric value ({exc})") from None
    bad = ~np.isfinite(raw["reading_gf"].to_numpy()) | ~np.isfinite(raw["t_s"].to_numpy())
    if bad.any():
        raise UserError(f"{raw_path}: line {int(np.argmax(bad)) + 2}: value is not a finite number")
    steps_path = run / "steps.csv"
    steps = None
    if steps_path.exists():
        try:
            steps = pd.read_csv(steps_path)
        except pd.errors.EmptyDataError:
            steps = None
        except (pd.errors.ParserError, UnicodeDecodeError) as exc:
            raise UserError(f"{steps_path}: unreadable ({exc})") from None
    if steps is None or steps.empty:
        steps = summarize_steps(raw)
    warn_if_partial(run)
    return raw, steps
