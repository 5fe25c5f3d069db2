"""The `make test` lanes (tests/support/lanes.py): a background worker never runs a test
that watches the clock, and every test runs exactly once."""

from __future__ import annotations

import random
from pathlib import Path

from tests.support.lanes import LaneScheduling, auto_workers, clock_bound_files, cores, lane_of


class _Cfg:
    def __init__(self, root: Path, n: int) -> None:
        self.rootpath = root
        self.n = n

    def getvalue(self, name):
        return ["popen"] * self.n if name == "tx" else None


class _Gateway:
    def __init__(self, gid: str) -> None:
        self.id = gid


class _Node:
    """A fake xdist worker: records what it was sent and hands back steals on request."""

    def __init__(self, gid: str, lane: str) -> None:
        self.gateway = _Gateway(gid)
        self.workerinput = {"tpods_lane": lane}
        self.shutting_down = False
        self.queue: list[int] = []
        self.ran: list[int] = []
        self.steal: list[int] | None = None

    def send_runtest_some(self, indices):
        self.queue.extend(indices)

    def send_steal(self, indices):
        self.steal = list(indices)

    def shutdown(self):
        self.shutting_down = True


def _files(tmp_path: Path) -> list[str]:
    (tmp_path / "tests" / "support").mkdir(parents=True)
    (tmp_path / "tests" / "support" / "emu.py").write_text("import time\ntime.sleep(0.1)\n")
    (tmp_path / "tests" / "test_fit.py").write_text("def test_a():\n    assert 1 + 1 == 2\n")
    (tmp_path / "tests" / "test_zenoh.py").write_text("import zenoh\n")
    (tmp_path / "tests" / "test_emu.py").write_text("from tests.support.emu import x\n")
    (tmp_path / "tests" / "test_rig.py").write_text("def test_b(bench):\n    pass\n")
    (tmp_path / "tests" / "test_fly.py").write_text(
        "import pytest\n\n@pytest.mark.flight\ndef test_c():\n    pass\n")
    ids = []
    for name in ("fit", "zenoh", "emu", "rig", "fly"):
        ids += [f"tests/test_{name}.py::test_{k}" for k in range(30)]
    return ids


def test_clock_words_and_support_imports_decide_the_lane(tmp_path):
    ids = _files(tmp_path)
    fg = clock_bound_files(ids, tmp_path, extra=("tests/test_other.py",))
    assert fg == {"tests/test_zenoh.py", "tests/test_emu.py", "tests/test_rig.py",
                  "tests/test_fly.py", "tests/test_other.py"}
    # a file that cannot be read is kept on a full-priority worker
    assert clock_bound_files(["tests/gone.py::test_x"], tmp_path) == {"tests/gone.py"}


def test_lane_of_worker_ids():
    n = cores()
    assert lane_of(f"gw{n}", "worksteal") == "background"
    assert lane_of(f"gw{n - 1}", "worksteal") == "foreground"
    assert lane_of(f"gw{n}", "load") == "foreground"  # only the lane scheduler knows lanes
    assert lane_of("master", "worksteal", n_cores=2) == "foreground"
    assert auto_workers() == (n + 1 if n >= 2 else 1)


def test_the_scheduler_never_gives_a_background_worker_a_clock_test(tmp_path):
    ids = _files(tmp_path)
    random.Random(3).shuffle(ids)
    fg_files = clock_bound_files(ids, tmp_path)
    nodes = [_Node("gw0", "foreground"), _Node("gw1", "foreground"), _Node("gw2", "background")]
    sched = LaneScheduling(_Cfg(tmp_path, 3))
    for node in nodes:
        sched.add_node(node)
        sched.add_node_collection(node, ids)
    sched.schedule()
    rng = random.Random(7)
    for _step in range(10_000):
        if sched.tests_finished:
            break
        for node in nodes:  # a worker answers a steal with the tests it has not started
            if node.steal is not None:
                given = [i for i in node.steal if i in node.queue[1:]]
                node.queue = [i for i in node.queue if i not in given]
                node.steal = None
                sched.remove_pending_tests_from_node(node, given)
        busy = [n for n in nodes if n.queue]
        if not busy:
            sched.check_schedule()
            continue
        node = rng.choice(busy)  # some worker finishes its current test
        i = node.queue.pop(0)
        node.ran.append(i)
        sched.mark_test_complete(node, i)
    assert sched.tests_finished
    for node in nodes:  # a worker told to shut down runs the test it kept back, then stops
        assert node.shutting_down and len(node.queue) <= 1
        node.ran += node.queue
    ran = [i for n in nodes for i in n.ran]
    assert sorted(ran) == list(range(len(ids)))  # each test once
    background = [ids[i] for i in nodes[2].ran]
    assert background and all(nid.split("::")[0] not in fg_files for nid in background)
    assert all(n.ran for n in nodes[:2])
