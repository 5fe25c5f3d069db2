"""The player on a structure (issue 18): several controllers, one loop, one commands.csv.

Every controller's watchdog is armed and fed while the loop lives; on every exit path (end,
stop, Ctrl-C, one controller's lost link) every controller is closed and its OFF confirmed
(the lost one closes by its own watchdog)."""

from __future__ import annotations

import json
import threading
import time

import numpy as np
import pandas as pd
import pytest

from bench.emulators import EmulatedValveController, serve_pty
from bench.valves import ValveController
from common.errors import DeviceError
from estimator.plant.inputs import phase_sine
from tpods.player import decode_command, play


@pytest.fixture
def two():
    emus = [EmulatedValveController(4), EmulatedValveController(4)]
    srvs = [serve_pty(e) for e in emus]
    try:
        yield emus, srvs
    finally:
        for s in srvs:
            s.stop()


def _phase8(duration):
    cmd_t, d = phase_sine(duration, 20.0, phases_rad=tuple(i * np.pi / 4 for i in range(8)))
    return cmd_t, d


def test_play_drives_every_module_and_records_one_file(two, tmp_path):
    emus, srvs = two
    cmd_t, duty = _phase8(1.0)
    msgs: dict[str, list[bytes]] = {"a": [], "b": []}
    with ValveController(srvs[0].path) as va, ValveController(srvs[1].path) as vb:
        res = play([("a", va), ("b", vb)], cmd_t, duty, out_dir=tmp_path,
                   publish={k: v.append for k, v in msgs.items()})
    assert res.status == "success" and res.final_state == (0.0,) * 8
    df = pd.read_csv(tmp_path / "commands.csv")
    assert list(df.columns) == ["t"] + [f"d{i}" for i in range(1, 9)]
    np.testing.assert_allclose(df.iloc[:-1, 1:].to_numpy(), duty[:-1], atol=6e-5)  # 4 decimals
    # each controller got its own block, each module's messages its own four duties
    for j, e in enumerate(emus):
        seen = {tuple(round(x, 3) for x in c.duties) for c in e.log if c.cause == "command"}
        assert tuple(round(x, 3) for x in duty[3, 4 * j:4 * j + 4]) in seen
        assert not any(e.duties)
    for j, k in enumerate(("a", "b")):
        sets = [decode_command(m) for m in msgs[k]]
        assert all(s["body"] == k for s in sets)
        first_set = next(s for s in sets if s["kind"] == "set")
        assert first_set["duty"] == pytest.approx(list(duty[0, 4 * j:4 * j + 4]), abs=1e-9)
        assert sets[-1]["kind"] == "end"
    meta = json.loads((tmp_path / "run.json").read_text())
    assert meta["valves_closed_confirmed"] is True and len(meta["valves"]) == 2


@pytest.mark.parametrize("how", ["stop", "interrupt"])
def test_every_exit_path_closes_every_controller(two, tmp_path, how):
    emus, srvs = two
    cmd_t, duty = _phase8(3.0)
    stop = threading.Event()
    n = {"k": 0}

    def publish(_payload: bytes) -> None:
        n["k"] += 1
        if n["k"] == 20:
            if how == "stop":
                stop.set()
            else:
                raise KeyboardInterrupt

    with ValveController(srvs[0].path) as va, ValveController(srvs[1].path) as vb:
        if how == "interrupt":
            with pytest.raises(KeyboardInterrupt):
                play([("a", va), ("b", vb)], cmd_t, duty, publish=publish, out_dir=tmp_path,
                     stop=stop)
        else:
            assert play([("a", va), ("b", vb)], cmd_t, duty, publish=publish, out_dir=tmp_path,
                        stop=stop).status == "aborted"
    for e in emus:
        assert not any(e.duties) and e.log[-1].cause == "command"
    assert json.loads((tmp_path / "run.json").read_text())["valves_closed_confirmed"] is True


def test_one_lost_link_closes_every_module(two, tmp_path):
    """Controller b's link goes (its server stops): the loop ends, a's valves are closed and
    confirmed by the host, b's close by b's own watchdog; the run says failed."""
    emus, srvs = two
    cmd_t, duty = _phase8(5.0)
    t0 = time.monotonic()

    def cut():
        time.sleep(1.0)
        srvs[1].stop()

    threading.Thread(target=cut, daemon=True).start()
    with ValveController(srvs[0].path) as va, ValveController(srvs[1].path) as vb:
        with pytest.raises(DeviceError, match="CLOSE THE AIR SUPPLY"):  # b's OFF unconfirmed
            play([("a", va), ("b", vb)], cmd_t, duty, out_dir=tmp_path, watchdog_ms=300)
    assert time.monotonic() - t0 < 4.5  # it did not play on to the end
    assert not any(emus[0].duties) and emus[0].log[-1].cause == "command"
    # b stopped hearing the host: its watchdog (300 ms) closes its valves
    emus[1].process_line("STATE?", now=time.monotonic() + 1.0)
    assert not any(emus[1].duties)
    meta = json.loads((tmp_path / "run.json").read_text())
    assert meta["status"] == "failed" and meta["valves_closed_confirmed"] is False


STRUCTURE = """
name = "truss"
[[modules]]
name = "a"
position_m = [-0.2, 0.0]
[[modules]]
name = "b"
position_m = [0.2, 0.0]
yaw_deg = 180
"""


@pytest.mark.parametrize("sig", [None, "SIGINT", "SIGTERM"])
def test_run_play_structure_cli(tpods_exe, two, tmp_path, sig):
    import signal
    import subprocess

    emus, srvs = two
    (tmp_path / "truss.toml").write_text(STRUCTURE)
    out = tmp_path / "run"
    cmd = [tpods_exe, "run", "play", "--structure", str(tmp_path / "truss.toml"), "--valves",
           f"a={srvs[0].path},b={srvs[1].path}", "--duration", "1" if sig is None else "20",
           "--out", str(out), "--no-progress", "--connect", "tcp/127.0.0.1:1", "--no-multicast"]
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    if sig is not None:
        end = time.monotonic() + 30
        while time.monotonic() < end and not any(any(e.duties) for e in emus):
            time.sleep(0.05)
        time.sleep(0.3)
        p.send_signal(getattr(signal, sig))
    stdout, stderr = p.communicate(timeout=60)
    assert p.returncode == {None: 0, "SIGINT": 130, "SIGTERM": 143}[sig], stderr
    for e in emus:
        assert not any(e.duties)
    df = pd.read_csv(out / "commands.csv")
    assert df.shape[1] == 9 and not df.iloc[-1, 1:].any()
    assert (out / "structure.toml").is_file()
    assert json.loads((out / "run.json").read_text())["valves_closed_confirmed"] is True


def test_run_play_structure_refuses_mismatched_valves(tpods_exe, tmp_path):
    from tests.support.cli import run_in_process

    (tmp_path / "truss.toml").write_text(STRUCTURE)
    r = run_in_process("run", "play", "--structure", str(tmp_path / "truss.toml"), "--valves",
                       "a=/dev/null", "--duration", "1")
    assert r.returncode == 2 and "the structure's modules are a, b" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
