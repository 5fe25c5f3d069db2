"""Merge the command streams of a structure's modules into one structure command (pure logic).

A structure is driven by N modules, each publishing its own four duties on
``tpods/<module>/cmd``. The live estimator needs the structure's command: the 4N duties in
force, module by module in the structure file's order (the columns of a structure run's
commands.csv). :class:`ModuleMerger` keeps each module's commands as a zero-order hold and
emits the structure command at every time any module switched:

- a stamp ``t`` is emitted once every module has sent a command stamped at or after ``t``
  (each module's stream is in time order, so its value at ``t`` is then known); the valve
  player sends every module's command of a row with the same stamp, so a row is emitted as
  soon as its last module's message arrives;
- a stamp still incomplete ``stale_s`` host seconds after its first message (a module's
  stream lagging or lost) is emitted with the lagging module's last value held, and
  counted (``incomplete``);
- a command that changes what an already emitted stamp holds (it arrived late, or out of
  order) makes the merger emit the corrected stamps again at the next :meth:`due` (once
  per batch of messages; same stamp: the consumer's later message wins,
  :meth:`estimator.live.align.LiveAligner.push_command`), counted in ``reemitted``;
- before a module's first command its valves are taken as closed (0 %).

Bad commands (unknown module, wrong width, non-finite or out-of-range duty, non-finite
time) are counted and skipped.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field

from estimator.live.counters import Counters

DEFAULT_STALE_S = 0.25
"""Longest (host seconds) a stamp waits for every module before it is emitted with the
lagging modules' last values held: above the player's 0.1 s heartbeat, so a healthy
stream never hits it."""


@dataclass
class MergeStats(Counters):
    cmds_in: int = 0
    cmds_bad: int = 0
    other_module: int = 0
    emitted: int = 0
    incomplete: int = 0
    reemitted: int = 0


@dataclass
class ModuleMerger:
    """Zero-order hold per module, structure commands out (see the module docstring).

    Args:
        modules: module names in the structure file's order.
        width: channels per module (4).
        stale_s: see :data:`DEFAULT_STALE_S`.
    """

    modules: tuple[str, ...]
    width: int = 4
    stale_s: float = DEFAULT_STALE_S
    stats: MergeStats = field(default_factory=MergeStats)

    def __post_init__(self) -> None:
        self.modules = tuple(self.modules)
        self.index = {m: i for i, m in enumerate(self.modules)}
        self._t: list[list[float]] = [[] for _ in self.modules]
        self._d: list[list[tuple[float, ...]]] = [[] for _ in self.modules]
        self._pending: list[float] = []          # stamps not emitted yet, sorted
        self._first_seen: dict[float, float] = {}  # pending stamp -> host time first seen
        self._emitted: dict[float, tuple[float, ...]] = {}
        self._emitted_t: list[float] = []         # sorted emitted stamps
        self._ends: set[str] = set()
        self.end_t: float | None = None
        self._dirty_from = math.inf  # earliest emitted stamp a late command may have changed

    # ------------------------------------------------------------------ input
    def push(self, module: str, t: float, duty, kind: str | None = None,
             arrival: float | None = None) -> list[tuple[float, tuple[float, ...]]]:
        """A module's command (lab time ``t``, its ``width`` duties, percent; ``arrival``
        host time it arrived, default ``t``: the stale wait runs from the first arrival of a
        stamp). Returns the structure commands to emit now, in order: ``(t, 4N duties)``."""
        self.stats.cmds_in += 1
        i = self.index.get(module)
        if i is None:
            self.stats.other_module += 1
            return []
        try:
            t = float(t)
            d = tuple(float(x) for x in duty)
        except (TypeError, ValueError):
            self.stats.cmds_bad += 1
            return []
        if len(d) != self.width or not math.isfinite(t) or not all(
                math.isfinite(x) and 0.0 <= x <= 100.0 for x in d):
            self.stats.cmds_bad += 1
            return []
        ts, ds = self._t[i], self._d[i]
        j = bisect.bisect_right(ts, t)
        if j > 0 and ts[j - 1] == t:
            ds[j - 1] = d
        else:
            ts.insert(j, t)
            ds.insert(j, d)
        if kind == "end":
            self._ends.add(module)
            if len(self._ends) == len(self.modules):
                self.end_t = t if self.end_t is None else max(self.end_t, t)
        if self._emitted_t and t <= self._emitted_t[-1]:
            # stamps already emitted may change: corrected in due(), once per batch of
            # messages (a lagging module's burst of late messages costs one pass, not one
            # pass and one filter rewind per message)
            self._dirty_from = min(self._dirty_from, t)
        if t not in self._emitted and t not in self._first_seen:
            bisect.insort(self._pending, t)
            self._first_seen[t] = t if arrival is None else float(arrival)
        return self._release(math.nan)

    def due(self, now: float) -> list[tuple[float, tuple[float, ...]]]:
        """The corrections of emitted stamps that late commands changed, then the stamps
        whose wait ran out at host time ``now`` (emitted with holds)."""
        return self._corrections() + self._release(now)

    def flush(self) -> list[tuple[float, tuple[float, ...]]]:
        """End of stream: every correction and every pending stamp."""
        return self._corrections() + self._release(math.inf)

    def _corrections(self) -> list[tuple[float, tuple[float, ...]]]:
        if self._dirty_from == math.inf:
            return []
        k = bisect.bisect_left(self._emitted_t, self._dirty_from)
        self._dirty_from = math.inf
        out = []
        for s in self._emitted_t[k:]:
            v = self.value_at(s)
            if v != self._emitted[s]:
                self._emitted[s] = v
                self.stats.reemitted += 1
                out.append((s, v))
        return out

    # ----------------------------------------------------------------- output
    def value_at(self, t: float) -> tuple[float, ...]:
        """The 4N duties in force at ``t`` (each module's latest command at or before ``t``)."""
        out: list[float] = []
        for ts, ds in zip(self._t, self._d, strict=True):
            j = bisect.bisect_right(ts, t) - 1
            out.extend(ds[j] if j >= 0 else (0.0,) * self.width)
        return tuple(out)

    @property
    def pending(self) -> int:
        return len(self._pending)

    def next_deadline(self) -> float | None:
        """Host time at which the oldest pending stamp is emitted by timeout."""
        if not self._pending:
            return None
        return min(self._first_seen[s] for s in self._pending) + self.stale_s

    def _release(self, now: float) -> list[tuple[float, tuple[float, ...]]]:
        known = min((ts[-1] if ts else -math.inf) for ts in self._t)
        out = []
        while self._pending:
            s = self._pending[0]
            if s <= known:
                pass
            elif now == math.inf or (now == now and now - self._first_seen[s] > self.stale_s):
                self.stats.incomplete += 1
            else:
                break
            self._pending.pop(0)
            del self._first_seen[s]
            v = self.value_at(s)
            self._emitted[s] = v
            bisect.insort(self._emitted_t, s)
            self.stats.emitted += 1
            out.append((s, v))
        return out
