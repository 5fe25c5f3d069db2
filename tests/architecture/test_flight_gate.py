"""The flight gate: flights one at a time, the background lane paused while one flies.

``flock`` locks belong to open file descriptions, so two threads that open the files
each on their own exclude each other as two processes would.
"""

from __future__ import annotations

import threading
import time

import pytest

from tests.support import flight_gate

pytestmark = pytest.mark.skipif(flight_gate.fcntl is None, reason="needs fcntl (POSIX)")


def _run(events: list[str], name: str, gate, release: threading.Event) -> threading.Thread:
    def body() -> None:
        with gate:
            events.append(f"{name} in")
            release.wait(10)
            events.append(f"{name} out")

    th = threading.Thread(target=body, daemon=True)
    th.start()
    return th


def _until(pred, timeout: float = 5.0) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.01)
    return pred()


@pytest.mark.parametrize(("first", "second"), [
    ("background", "flight"), ("flight", "background"), ("flight", "flight")])
def test_the_second_waits_for_the_first(tmp_path, first, second):
    make = {"flight": flight_gate.flight, "background": flight_gate.background_test}
    events: list[str] = []
    go_a, go_b = threading.Event(), threading.Event()
    a = _run(events, "a", make[first](tmp_path), go_a)
    assert _until(lambda: "a in" in events)
    b = _run(events, "b", make[second](tmp_path), go_b)
    time.sleep(0.3)
    assert "b in" not in events, f"a {second} started while a {first} ran"
    go_a.set()
    a.join(5)
    assert _until(lambda: "b in" in events), f"the {second} never started"
    go_b.set()
    b.join(5)
    assert events == ["a in", "a out", "b in", "b out"]


def test_background_tests_do_not_wait_for_each_other(tmp_path):
    events: list[str] = []
    go = threading.Event()
    a = _run(events, "a", flight_gate.background_test(tmp_path), go)
    b = _run(events, "b", flight_gate.background_test(tmp_path), go)
    assert _until(lambda: "a in" in events and "b in" in events)
    go.set()
    a.join(5)
    b.join(5)


def test_a_queued_flight_holds_back_the_next_background_test(tmp_path):
    """A flight waiting for the gate keeps new background tests out (no starvation)."""
    events: list[str] = []
    go_bg, go_fl, go_bg2 = threading.Event(), threading.Event(), threading.Event()
    bg = _run(events, "bg", flight_gate.background_test(tmp_path), go_bg)
    assert _until(lambda: "bg in" in events)
    fl = _run(events, "fl", flight_gate.flight(tmp_path), go_fl)
    time.sleep(0.3)  # the flight now holds the flight lock and waits for the gate
    bg2 = _run(events, "bg2", flight_gate.background_test(tmp_path), go_bg2)
    time.sleep(0.3)
    assert "fl in" not in events and "bg2 in" not in events
    go_bg.set()
    assert _until(lambda: "fl in" in events)
    time.sleep(0.2)
    assert "bg2 in" not in events, "a background test started while a flight flew"
    go_fl.set()
    assert _until(lambda: "bg2 in" in events)
    go_bg2.set()
    for th in (bg, fl, bg2):
        th.join(5)
    assert events == ["bg in", "bg out", "fl in", "fl out", "bg2 in", "bg2 out"]
