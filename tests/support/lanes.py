"""Two lanes for ``make test`` (pytest-xdist): wall-clock tests keep the machine's cores.

About a third of the suite waits on wall-clock time: emulated devices and simulated lab
runs played in real time, Zenoh streams, subprocess pipelines with lag checks. On 2
workers that waiting left a core idle for about 180 of the suite's 680 worker-seconds.
A third equal worker fills it, but then the demo's emulated valves switched 43-228 ms
late on average and the demo tests skipped their estimator checks as "too loaded".

So ``-n auto`` starts one worker per core (the *foreground* lane, normal priority, any
test) plus one *background* worker (``os.nice(BACKGROUND_NICE)``; its children inherit
it) that takes only tests that do not watch the clock. The kernel gives the background
worker the CPU the foreground leaves idle and about a tenth of it otherwise, so a
real-time test competes with at most one other full-weight worker, as before. While a test
marked ``flight`` flies, the background worker starts no test (tests/support/flight_gate.py:
a machine that never idles starved the kernel threads that move a pty's bytes).

Which tests watch the clock is read from their source, not from a list kept by hand: a
test file that mentions any of :data:`CLOCK_WORDS` (Zenoh, process pipelines, ptys,
sockets, emulators, sleeps, clocks, the ``bench`` fixture; not a plain ``subprocess.run``
of a command that computes and exits) runs in the foreground lane
only, as do the files of ``EXTRA_FOREGROUND`` (tests/conftest.py). Erring that way costs
only speed. The scheduler is xdist's work stealing with one rule added: a background
worker is never sent, and never steals, a foreground-only test.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from xdist.scheduler.worksteal import MIN_PENDING, NodePending, WorkStealingScheduling

BACKGROUND_NICE = 10
CLOCK_WORDS = re.compile(
    r"zenoh|Popen|\bpty\b|openpty|socket\.|serial_for_url|sleep\(|perf_counter|monotonic\("
    r"|time\.time\(|def test_\w+\([^)]*\bbench\b|\"demo\"|--time-scale|\"play\"|\"plant\""
    r"|mark\.flight")
"""Words of a test file that waits on wall-clock time: Zenoh, process pipelines, ptys,
sockets, serial emulators, sleeps, clocks, the emulated ``bench`` fixture, the demo, the
player and the plant (which run lab time at a time scale), and the ``flight`` mark (a flight
on the background worker would wait for the gate that worker itself holds:
tests/support/flight_gate.py)."""


def cores() -> int:
    """CPUs this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover (not Linux)
        return os.cpu_count() or 1


def auto_workers() -> int:
    """``-n auto``: a foreground worker per core and one background worker (one core: 1)."""
    n = cores()
    return n + 1 if n >= 2 else 1


def auto_workers_env() -> int:
    """:func:`auto_workers`, or ``PYTEST_XDIST_AUTO_NUM_WORKERS`` when set (as xdist)."""
    v = os.environ.get("PYTEST_XDIST_AUTO_NUM_WORKERS", "")
    return int(v) if v.isdigit() and int(v) > 0 else auto_workers()


def lane_of(worker_id: str, dist: str, n_cores: int | None = None) -> str:
    """``"background"`` for worker ``gwK`` with K >= the number of cores under the lane
    scheduler (``--dist worksteal``), else ``"foreground"``."""
    m = re.fullmatch(r"gw(\d+)", worker_id or "")
    n = cores() if n_cores is None else n_cores
    return "background" if dist == "worksteal" and m and int(m.group(1)) >= n else "foreground"


SUPPORT_IMPORT = re.compile(r"from tests\.support\.(\w+) import|from tests\.support import (\w+)")


def clock_bound_files(nodeids: list[str], root: Path, extra: tuple[str, ...] = ()) -> set[str]:
    """The test files (as in the node ids) that run in the foreground lane only: those
    that mention a clock word, or import a ``tests.support`` module that does."""
    support = root / "tests" / "support"
    seen: dict[Path, bool] = {}

    def check(path: Path) -> bool:
        if path in seen:
            return seen[path]
        seen[path] = True
        try:
            text = path.read_text(errors="replace")
        except OSError:
            return True
        found = bool(CLOCK_WORDS.search(text)) or any(
            check(support / f"{m.group(1) or m.group(2)}.py") for m in SUPPORT_IMPORT.finditer(text))
        seen[path] = found
        return found

    return set(extra) | {p for p in {nid.split("::")[0] for nid in nodeids} if check(root / p)}


class LaneScheduling(WorkStealingScheduling):
    """xdist work stealing where background workers take only clock-free tests."""

    extra_foreground: tuple[str, ...] = ()

    def schedule(self) -> None:
        if self.collection is None and self.collection_is_completed:
            col = next(iter(self.node2collection.values()))
            files = clock_bound_files(col, Path(self.config.rootpath), self.extra_foreground)
            self._fg_only = [nid.split("::")[0] in files for nid in col]
        super().schedule()

    @staticmethod
    def _bg(node) -> bool:
        return node.workerinput.get("tpods_lane") == "background"

    def _take(self, node, num: int) -> None:
        """Send ``node`` up to ``num`` pending tests it may run, in collection order."""
        if num <= 0:
            return
        if not self._bg(node):
            self._send_tests(node, num)
            return
        picked = [i for i in self.pending if not self._fg_only[i]][:num]
        if picked:
            chosen = set(picked)
            self.pending[:] = [i for i in self.pending if i not in chosen]
            self.node2pending[node].extend(picked)
            node.send_runtest_some(picked)

    def check_schedule(self) -> None:
        """xdist's :meth:`WorkStealingScheduling.check_schedule` with the lane rule."""
        nodes_up = [NodePending(node, pending) for node, pending in self.node2pending.items()
                    if not node.shutting_down]

        def idle_nodes():
            return [node for node, pending in nodes_up if len(pending) < MIN_PENDING]

        idle = idle_nodes()
        if not idle:
            return
        if self.pending:
            # foreground workers first: they can take anything, the background the rest
            idle.sort(key=self._bg)
            for k, node in enumerate(idle):  # rounded up: a last test goes to a worker
                self._take(node, -(-len(self.pending) // (len(idle) - k)))
            idle = idle_nodes()
            if not idle:
                return
        if self.steal_requested_from_node is not None:
            return
        thief = min(idle, key=self._bg)  # a foreground worker if one is idle
        best, take = None, []
        for node, pending in nodes_up:
            if node is thief:
                continue
            queue = pending[MIN_PENDING:] if len(pending) > MIN_PENDING else []
            if self._bg(thief):
                queue = [i for i in queue if not self._fg_only[i]]
            n = min(len(pending) // 2, len(queue))
            if n > len(take):
                best, take = node, queue[-n:]
        if best is None:
            # nothing to steal for the idle workers: those that may run every pending test
            # (or all, when nothing is pending) finish their last test and stop
            for node in idle:
                if not self.pending or not self._bg(node):
                    node.shutdown()
            return
        best.send_steal(take)
        self.steal_requested_from_node = best
