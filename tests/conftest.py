"""Shared test fixtures (their helpers live in tests/support/)."""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

import pytest

from common.zenoh_net import open_session
from tests.support import flight_gate
from tests.support.bench import Bench
from tests.support.net import free_port, wait_for
from tests.support.sim import sim_run

os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture(scope="session")
def tpods_exe() -> str:
    """The installed ``tpods`` console script (the one a user runs)."""
    exe = Path(sys.executable).with_name("tpods")
    if exe.exists():
        return str(exe)
    found = shutil.which("tpods")
    if not found:
        pytest.fail("the tpods console script is not installed; run `make setup`")
    return found


@pytest.fixture
def zenoh_pair():
    """Two in-process peers: ``pub`` listens, ``sub`` connects (loopback, no multicast)."""
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    pub = open_session(listen=[ep], no_multicast=True)
    sub = open_session(connect=[ep], no_multicast=True)
    assert wait_for(lambda: len(pub.info.peers_zid()) > 0, 10.0), "peers did not connect"
    try:
        yield pub, sub, ep
    finally:
        sub.close()
        pub.close()


def _lock_folder(config) -> Path:
    """The run's shared temporary folder (all xdist workers' basetemps are inside it)."""
    return config._tmp_path_factory.getbasetemp().parent


@pytest.fixture(autouse=True)
def _one_flight_at_a_time(request):
    """Tests marked ``flight`` (a demo or lab run: the simulated plant, the player and the
    live estimator as processes on the lab clock, judged by how late the emulated valves
    switched) never run at the same time, on any xdist worker, nor beside a test of the
    background lane (tests/support/flight_gate.py says why: kernel threads starved for a
    second when the machine never idles)."""
    if request.node.get_closest_marker("flight") is None:
        yield
        return
    with flight_gate.flight(_lock_folder(request.config)):
        yield


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """A background-lane worker waits while a flight flies (its set-up included)."""
    if getattr(item.config, "workerinput", {}).get("tpods_lane") != "background":
        yield
        return
    with flight_gate.background_test(_lock_folder(item.config)):
        yield


@pytest.fixture
def bench():
    b = Bench()
    yield b
    b.stop()


@pytest.fixture(scope="session")
def runs_mixed():
    """Three 10 s runs with different masses, seeds and 15 % dropped frames."""
    return [sim_run(m, i, s, duration=10.0, drop=0.15)
            for m, i, s in ((2.268, 3.78e-3, 0), (1.4, 2.2e-3, 1), (3.3, 5.9e-3, 2))]


# files whose tests take longest (the demo end-to-ends and the characterisation session wait on
# lab time; the coverage and Monte Carlo studies compute): run first, so that no parallel worker
# is left with one of them at the end while the others idle (`make test`, pytest-xdist)
LONGEST_FIRST = (
    # the flights (marked ``flight``: one at a time) together at the front: the first worker
    # takes them in one block and flies them one after the other, without waiting
    "tests/tpods/test_demo.py", "tests/tpods/test_demo_structure.py", "tests/tpods/test_e2e.py",
    "tests/tpods/test_demo_vehicle.py", "tests/tpods/test_plant_vehicle.py",
    "tests/net/test_lab_faults.py",
    "tests/bench/test_session.py", "tests/estimator/batch/test_consider.py",
    "tests/estimator/test_montecarlo.py", "tests/estimator/test_sweep.py",
    "tests/estimator/plant/test_sim.py", "tests/tpods/cli/test_estimate_structure_models.py",
)


def pytest_collection_modifyitems(config, items):
    """The files of :data:`LONGEST_FIRST` first, in that order; every file's tests stay
    together and in their order (module fixtures are shared as before)."""
    rank = {path: i for i, path in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.nodeid.split("::")[0], len(rank)))
    # tests marked slow (many-seed Monte Carlo) run only when asked for: pytest -m slow
    if "slow" not in (config.getoption("markexpr") or ""):
        skip = pytest.mark.skip(reason="slow: run with pytest -m slow (or make test-slow)")
        for item in items:
            if item.get_closest_marker("slow") is not None:
                item.add_marker(skip)


# files that wait on wall-clock time without saying so in the words tests/support/lanes.py
# looks for: they run on a full-priority worker only
EXTRA_FOREGROUND: tuple[str, ...] = ()


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_auto_num_workers(config):
    """``-n auto``: a worker per core plus one low-priority worker (tests/support/lanes.py)."""
    from tests.support.lanes import auto_workers_env

    return auto_workers_env()


@pytest.hookimpl(optionalhook=True)
def pytest_configure_node(node):
    """Tell each worker its lane (read back in :func:`pytest_configure` and the scheduler)."""
    from tests.support.lanes import lane_of

    node.workerinput["tpods_lane"] = lane_of(node.gateway.id, node.config.getoption("dist"))


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """``--dist worksteal`` with the lane rule of tests/support/lanes.py."""
    if config.getoption("dist") != "worksteal":
        return None
    from tests.support.lanes import LaneScheduling

    sched = LaneScheduling(config, log)
    sched.extra_foreground = EXTRA_FOREGROUND
    return sched


def pytest_addoption(parser):
    parser.addoption("--update-goldens", action="store_true", default=False,
                     help="rewrite the golden outputs of tests/regression (prints what moved)")


def pytest_configure(config):
    from tests.support import golden

    golden.UPDATE["on"] = bool(config.getoption("--update-goldens", default=False))
    if getattr(config, "workerinput", {}).get("tpods_lane") == "background":
        from tests.support.lanes import BACKGROUND_NICE

        os.nice(BACKGROUND_NICE)
