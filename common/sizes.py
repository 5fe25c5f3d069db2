"""Memory and time of the long commands (``sim``, ``design``, ``estimate crlb``; the memory
of ``estimate montecarlo``), estimated
from their options before anything is allocated.

A command refuses work whose arrays would take more than half the memory this machine
has available, with one line naming the options and the size; work that fits but takes
more than :data:`ANNOUNCE_S` seconds is announced on stderr with its expected duration.
The per-sample costs below were measured on this toolkit's code (``tracemalloc`` peak and
wall time, 120 s runs at 50-5000 Hz, a 2-core machine under load) and rounded up: they
are estimates for a message, not a promise.
"""

from __future__ import annotations

import math
import os
import sys

from common.errors import UserError

ANNOUNCE_S = 5.0  # announce work expected to take longer than this

# tpods sim: peak bytes and seconds per pose and per command row (integration, noise,
# the written CSV rows)
SIM_BYTES_PER_POSE = 800.0
SIM_BYTES_PER_CMD = 2000.0
SIM_S_PER_POSE = 2e-5
SIM_S_PER_CMD = 2e-5
# the CRLB (estimate crlb, each design candidate): per grid segment (a pose, a command
# switch or a 10 ms step), for n = 6 + estimated parameters, about n^2 doubles several times
CRLB_BYTES_PER_SEGMENT_N2 = 60.0
CRLB_S_PER_SEGMENT_N2 = 2e-7
CRLB_MAX_STEP_S = 0.01  # estimator.batch.crlb.DEFAULT_MAX_STEP_S (not imported: heavy)
# tpods design keeps every scored candidate's trajectory and sensitivities
DESIGN_KEPT_BYTES_PER_POSE = 450.0
# tpods estimate montecarlo: the per-time statistics and example traces of the module's
# vectorised filter (~1.1-3.2 kB per pose measured, 2-200 runs) plus a per-run state; a
# structure's Monte Carlo simulates and fits one run at a time (~7 kB per pose)
MC_BYTES_PER_POSE = 3500.0
MC_BYTES_PER_RUN = 2e4
MC_STRUCTURE_BYTES_PER_POSE = 10000.0


def available_memory() -> float | None:
    """Bytes of memory available to a new allocation (MemAvailable), None if unknown."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024.0
    except (OSError, ValueError, IndexError):
        pass
    try:
        return float(os.sysconf("SC_AVPHYS_PAGES")) * float(os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return None


def number(v: float) -> str:
    """``1e9`` as ``1e9``, ``120`` as ``120``, ``1.2e11`` as ``1.2e11`` (as a user types it)."""
    if not math.isfinite(v):
        return str(v)
    if abs(v) < 1e6:
        return f"{v:.6g}"
    text = f"{v:.3g}"
    if "e" in text:
        mant, exp = text.split("e")
        text = f"{mant}e{int(exp)}"
    return text


def size_text(n_bytes: float) -> str:
    """``9.6e13`` -> ``96 TB`` (decimal units, two significant digits)."""
    if not math.isfinite(n_bytes):
        return "unbounded"
    for unit, scale in (("EB", 1e18), ("PB", 1e15), ("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n_bytes >= scale:
            v = n_bytes / scale
            return f"{v:.2g} {unit}" if v < 10 else f"{v:.0f} {unit}"
    return f"{n_bytes:.0f} B"


def duration_text(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "forever"
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 2 * 3600:
        return f"{seconds / 60:.0f} min"
    if seconds < 3 * 86400:
        return f"{seconds / 3600:.1f} h"
    return f"{seconds / 86400:.3g} days"


def samples(duration_s: float, rate_hz: float) -> float:
    """Number of samples (a float: no overflow for absurd options)."""
    n = duration_s * rate_hz
    return n + 1.0 if math.isfinite(n) else math.inf


def samples_text(duration_s: float, rate_hz: float) -> str:
    """``samples(duration_s, rate_hz)`` as text, also when it overflows a float."""
    n = samples(duration_s, rate_hz)
    if math.isfinite(n):
        return number(n)
    e = math.log10(duration_s) + math.log10(rate_hz)
    return f"{10 ** (e - math.floor(e)):.2g}e{math.floor(e)}"


def refuse_if_too_big(what: str, n_bytes: float, fix: str, memory: float | None = None) -> None:
    """Raise UserError ``"<what> (~SIZE); this machine has AVAIL available: <fix>"`` when
    ``n_bytes`` exceeds half the available memory (``memory``: for tests)."""
    avail = available_memory() if memory is None else memory
    if avail is None:
        avail = 8e9  # unknown: assume a small lab PC
    if n_bytes > avail / 2:
        need = f"~{size_text(n_bytes)}" if math.isfinite(n_bytes) else "unbounded"
        raise UserError(f"{what} (needs {need} memory; this machine has "
                        f"{size_text(avail)} available): {fix}")


def announce(seconds: float, what: str, stream=None) -> None:
    """One line on stderr when ``what`` is expected to take longer than :data:`ANNOUNCE_S`."""
    if seconds > ANNOUNCE_S:
        print(f"tpods: {what} will take about {duration_text(seconds)}", file=stream or sys.stderr,
              flush=True)


def sim_cost(n_poses: float, n_cmds: float) -> tuple[float, float]:
    """(bytes, seconds) of a simulation with ``n_poses`` poses and ``n_cmds`` command rows."""
    return (SIM_BYTES_PER_POSE * n_poses + SIM_BYTES_PER_CMD * n_cmds,
            SIM_S_PER_POSE * n_poses + SIM_S_PER_CMD * n_cmds)


def crlb_segments(n_poses: float, n_cmds: float, span_s: float) -> float:
    """Grid segments of a CRLB: poses, command switches and at most 10 ms steps."""
    return n_poses + n_cmds + span_s / CRLB_MAX_STEP_S


def crlb_cost(segments: float, n_params: int) -> tuple[float, float]:
    """(bytes, seconds) of one CRLB over ``segments`` grid segments."""
    n2 = float(6 + n_params) ** 2
    return CRLB_BYTES_PER_SEGMENT_N2 * n2 * segments, CRLB_S_PER_SEGMENT_N2 * n2 * segments


def montecarlo_bytes(n_poses: float, n_cmds: float, runs: int, structure: bool) -> float:
    """Peak bytes of a Monte Carlo over ``n_poses`` poses and ``n_cmds`` command rows."""
    per_pose = MC_STRUCTURE_BYTES_PER_POSE if structure else MC_BYTES_PER_POSE
    return per_pose * n_poses + SIM_BYTES_PER_CMD * n_cmds + MC_BYTES_PER_RUN * runs
