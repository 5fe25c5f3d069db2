"""What the host did while a bench row ran: CPU steal, iowait, other processes' CPU, load.

A :class:`Window` is opened before a row's timed section and closed after it; in between
it reads nothing (no thread, no polling), so it costs the row nothing. At each end it
reads ``/proc/stat`` (CPU ticks of all CPUs), ``/proc/loadavg``, this process's CPU time
with that of its waited-for children (``getrusage``), and times a small fixed workload,
the *probe*, just outside the window. :func:`host_conditions` turns two such
:class:`Snapshot` s into the figures a row reports (its ``host`` field):

- ``steal_pct``: CPU time the hypervisor gave to other guests, share of all CPUs' time
- ``iowait_pct``: idle time with disk I/O outstanding, share of all CPUs' time
- ``others_cpu_pct``: user+system time of every process that is not the bench (all busy
  ticks minus the bench's own CPU time), share of all CPUs' time
- ``own_cpu_s`` (the bench's CPU seconds; about its wall time on a quiet host when it
  runs one thread), ``own_cpu_pct``, ``idle_pct``, ``load1_start``/``load1_end`` (1-min load average,
  which counts the bench's own processes too), ``probe_before_ms``/``probe_after_ms`` and
  ``probe_change_pct`` (how much the probe moved across the row).

Where ``/proc`` is missing (not Linux) the ``/proc`` figures are None and only the probe
is measured. The rule that judges these figures is in :mod:`benchmarks.verdict`.
"""

from __future__ import annotations

import math
import os
import resource
import threading
import time
from dataclasses import dataclass

import numpy as np

PROBE_REPEATS = 3
PROBE_LOOPS = 2000


@dataclass(frozen=True)
class CpuTicks:
    """Cumulative CPU ticks of all CPUs, the first line of ``/proc/stat``."""

    user: int
    nice: int
    system: int
    idle: int
    iowait: int
    irq: int
    softirq: int
    steal: int

    @property
    def total(self) -> int:
        return (self.user + self.nice + self.system + self.idle + self.iowait + self.irq
                + self.softirq + self.steal)

    @property
    def busy(self) -> int:
        """Ticks spent running processes (user, nice, system; guest time is inside user)."""
        return self.user + self.nice + self.system


@dataclass(frozen=True)
class LoadAvg:
    """``/proc/loadavg``: load averages and the runnable / total task counts."""

    load1: float
    load5: float
    load15: float
    runnable: int
    tasks: int


@dataclass(frozen=True)
class Snapshot:
    """One reading of the host at a window's end (see :func:`snapshot`)."""

    time_s: float
    own_cpu_s: float
    ticks: CpuTicks | None
    load: LoadAvg | None
    probe_ms: float | None = None


def parse_proc_stat(text: str) -> CpuTicks | None:
    """The aggregate ``cpu`` line of a ``/proc/stat`` text; None if it has none or too few
    fields (kernels before 2.6.11 had no steal column)."""
    for line in text.splitlines():
        parts = line.split()
        if parts and parts[0] == "cpu":
            try:
                v = [int(x) for x in parts[1:9]]
            except ValueError:
                return None
            return CpuTicks(*v) if len(v) == 8 else None
    return None


def parse_loadavg(text: str) -> LoadAvg | None:
    """``"0.52 0.61 0.70 2/345 6789"`` -> LoadAvg(0.52, 0.61, 0.70, 2, 345); None if malformed."""
    parts = text.split()
    try:
        run, tasks = parts[3].split("/")
        return LoadAvg(float(parts[0]), float(parts[1]), float(parts[2]), int(run), int(tasks))
    except (IndexError, ValueError):
        return None


def _read(path: str) -> str | None:
    try:
        with open(path) as f:
            return f.read()
    except OSError:
        return None


def read_cpu_ticks() -> CpuTicks | None:
    text = _read("/proc/stat")
    return parse_proc_stat(text) if text is not None else None


def read_loadavg() -> LoadAvg | None:
    text = _read("/proc/loadavg")
    return parse_loadavg(text) if text is not None else None


def own_cpu_s() -> float:
    """User+system seconds of this process and of its children that have been waited for
    (a bench's subprocesses and multiprocessing workers, once joined)."""
    s, c = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return s.ru_utime + s.ru_stime + c.ru_utime + c.ru_stime


def ticks_per_s() -> float:
    try:
        return float(os.sysconf("SC_CLK_TCK"))
    except (ValueError, OSError, AttributeError):
        return 100.0


_ROT = np.array([[math.cos(0.1), -math.sin(0.1)], [math.sin(0.1), math.cos(0.1)]])


def probe_ms(repeats: int = PROBE_REPEATS) -> float:
    """Median wall time of a fixed workload (small numpy products in a Python loop, the
    mix of the filters' inner loops), ms: the host's speed at this moment."""
    times = []
    for _ in range(repeats):
        v = np.array([1.0, 0.0])
        acc = 0.0
        t0 = time.perf_counter()
        for i in range(PROBE_LOOPS):
            v = _ROT @ v
            acc += math.sin(i * 1e-3) * float(v @ v)
        times.append((time.perf_counter() - t0) * 1e3)
    return float(np.median(times))


def snapshot(probe: bool = False) -> Snapshot:
    """Read the host now; the probe is run first when asked, so it is not inside a window
    that starts here."""
    p = probe_ms() if probe else None
    return Snapshot(time.monotonic(), own_cpu_s(), read_cpu_ticks(), read_loadavg(), p)


def _pct(part: float, whole: float) -> float:
    return round(100.0 * part / whole, 3)


def host_conditions(before: Snapshot, after: Snapshot, hz: float = 100.0) -> dict:
    """The host figures of the window between two snapshots (pure: no reading here).

    ``hz``: ticks per second of ``/proc/stat`` (``SC_CLK_TCK``), to put the bench's own CPU
    seconds into ticks. Figures that cannot be measured are None."""
    out: dict = {"seconds": round(after.time_s - before.time_s, 3),
                 "own_cpu_s": round(after.own_cpu_s - before.own_cpu_s, 3),
                 "steal_pct": None, "iowait_pct": None, "others_cpu_pct": None,
                 "own_cpu_pct": None, "idle_pct": None}
    a, b = before.ticks, after.ticks
    if a is not None and b is not None and b.total > a.total:
        total = b.total - a.total
        own = (after.own_cpu_s - before.own_cpu_s) * hz
        out.update(steal_pct=_pct(b.steal - a.steal, total), iowait_pct=_pct(b.iowait - a.iowait, total),
                   others_cpu_pct=_pct(max(b.busy - a.busy - own, 0.0), total),
                   own_cpu_pct=_pct(min(own, total), total), idle_pct=_pct(b.idle - a.idle, total))
    out["load1_start"] = before.load.load1 if before.load else None
    out["load1_end"] = after.load.load1 if after.load else None
    out["probe_before_ms"] = _round(before.probe_ms)
    out["probe_after_ms"] = _round(after.probe_ms)
    out["probe_change_pct"] = probe_change_pct(before.probe_ms, after.probe_ms)
    return out


def _round(x: float | None) -> float | None:
    return None if x is None else round(x, 3)


def probe_change_pct(before_ms: float | None, after_ms: float | None) -> float | None:
    """How far the probe moved across a window: |after - before| over the faster, %."""
    if before_ms is None or after_ms is None or min(before_ms, after_ms) <= 0:
        return None
    return round(100.0 * abs(after_ms - before_ms) / min(before_ms, after_ms), 2)


class Window:
    """The host during a row's timed section: ``w = Window()`` before it, then the row
    takes ``**w.timed()`` (which closes the window on its first call, so rows that share
    a section share one window)::

        w = Window()
        ... timed work ...
        w.stop()                     # optional: close it before untimed work
        row = {"case": ..., "ok": ..., **w.timed(ok_untimed=converged)}

    ``ok_untimed``: the part of the row's ``ok`` that does not depend on timing (an
    estimate's accuracy, a complete file...); a row that fails it is NO on any host.
    ``Window.spanning(w1, w2)``: from the start of ``w1`` to the end of ``w2`` (a row
    measured over several sections)."""

    def __init__(self) -> None:
        self.before = snapshot(probe=True)
        self.after: Snapshot | None = None

    @classmethod
    def spanning(cls, first: Window, last: Window) -> Window:
        last.stop()
        w = cls.__new__(cls)
        w.before, w.after = first.before, last.after
        return w

    def stop(self) -> dict:
        if self.after is None:
            s = snapshot(probe=False)  # read the host, then probe: outside the window
            self.after = Snapshot(s.time_s, s.own_cpu_s, s.ticks, s.load, probe_ms())
        return host_conditions(self.before, self.after, ticks_per_s())

    def timed(self, ok_untimed: bool | None = None) -> dict:
        out: dict = {"timed": True, "host": self.stop()}
        if ok_untimed is not None:
            out["ok_untimed"] = bool(ok_untimed)
        return out


class LoadSampler:
    """Samples ``/proc/loadavg`` every ``period_s`` in a daemon thread of the bench runner
    (which only waits for its case's process meanwhile): the largest 1-min load and
    runnable task count over a case."""

    def __init__(self, period_s: float = 1.0) -> None:
        self.load1_max: float | None = None
        self.runnable_max: int | None = None
        self._stop = threading.Event()
        self._period = period_s
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:
            la = read_loadavg()
            if la is not None:
                self.load1_max = max(self.load1_max or 0.0, la.load1)
                self.runnable_max = max(self.runnable_max or 0, la.runnable)
            if self._stop.wait(self._period):
                return

    def stop(self) -> dict:
        self._stop.set()
        self._thread.join(5)
        return {"load1_max": self.load1_max, "runnable_max": self.runnable_max}
