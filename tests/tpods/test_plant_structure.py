"""The plant-in-the-loop simulator following a structure's controllers (issue 18)."""

from __future__ import annotations

import time

import numpy as np

from bench.emulators import EmulatedValveController
from common.structure import Structure
from estimator.plant.model import PlantParams
from estimator.plant.output import tracked_pose
from tpods.clock import LabClock
from tpods.plant_loop import MocapNoise, PlantLoop, StructureThrust, StructureValves

TRUSS = {"name": "truss", "modules": [
    {"name": "a", "position_m": [-0.2, 0.0], "yaw_deg": 0.0},
    {"name": "b", "position_m": [0.2, 0.05], "yaw_deg": 90.0}]}


def test_structure_valves_compose_every_module_row():
    a, b = EmulatedValveController(4), EmulatedValveController(4)
    rows = []
    StructureValves([a, b]).add_listener(lambda t, d: rows.append(d))
    a.process_line("DUTY* 50 0 0 0")
    b.process_line("DUTY* 0 0 30 40")
    a.process_line("OFF")
    assert rows == [(50.0, 0, 0, 0, 0, 0, 0, 0), (50.0, 0, 0, 0, 0, 0, 30.0, 40.0),
                    (0, 0, 0, 0, 0, 0, 30.0, 40.0)]


def test_plant_follows_both_controllers_and_reports_the_tracked_frame():
    s = Structure.from_dict(TRUSS)
    a, b = EmulatedValveController(4), EmulatedValveController(4)
    poses = []
    params = PlantParams(1.6, 0.03, cx=0.03, cy=-0.01)
    plant = PlantLoop(StructureValves([a, b]), params, StructureThrust(s),
                      lambda k, t, x, y, psi, occ: poses.append((t, x, y, psi)),
                      clock=LabClock(4.0), pose_rate_hz=60, noise=MocapNoise(0.0, 0.0))
    with plant:
        time.sleep(0.1)
        a.process_line("DUTY* 50 50 0 0")      # a pushes +y, b turns the truss
        b.process_line("DUTY* 40 0 40 0")
        time.sleep(0.5)
        a.process_line("OFF")
        b.process_line("OFF")
        time.sleep(0.1)
    t, states = plant.truth_arrays()
    assert len(poses) == len(t) > 20
    got = np.array([p[1:] for p in poses])
    want = tracked_pose(states, params.cx, params.cy)
    want[:, 2] = np.remainder(want[:, 2] + np.pi, 2 * np.pi) - np.pi
    np.testing.assert_allclose(got, want, atol=1e-12)
    assert np.ptp(states[:, 2]) > 1e-3 and np.ptp(states[:, 1]) > 1e-4  # it turned and moved
    # the switches the plant saw: both controllers' rows, in the structure's channel order
    assert [d for _, d in plant.switches][:2] == [(50.0, 50.0, 0, 0, 0, 0, 0, 0),
                                                  (50.0, 50.0, 0, 0, 40.0, 0, 40.0, 0)]


def test_run_plant_structure_follows_run_play_structure(tpods_exe, tmp_path):
    """The two commands together: `run plant --structure` serves one controller per module,
    `run play --structure` drives them; the plant sees the valve changes of both."""
    import subprocess

    from tests.support.net import free_port

    (tmp_path / "truss.toml").write_text(
        'name = "truss"\n[[modules]]\nname = "a"\nposition_m = [-0.2, 0.0]\n'
        '[[modules]]\nname = "b"\nposition_m = [0.2, 0.05]\nyaw_deg = 90\n')
    plant = subprocess.Popen([tpods_exe, "run", "plant", "--structure", str(tmp_path / "truss.toml"),
                              "--mocap", f"udp:127.0.0.1:{free_port()}", "--duration", "30",
                              "--truth-out", str(tmp_path / "truth")],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        paths = {}
        while len(paths) < 2:
            line = plant.stdout.readline()
            assert line, plant.stderr.read()
            name, path = line.strip().removeprefix("valves ").split(": ")
            paths[name] = path
        r = subprocess.run([tpods_exe, "run", "play", "--structure", str(tmp_path / "truss.toml"),
                            "--valves", f"a={paths['a']},b={paths['b']}", "--duration", "2",
                            "--no-progress", "--connect", "tcp/127.0.0.1:1", "--no-multicast"],
                           capture_output=True, text=True, timeout=60)
        assert r.returncode == 0, r.stderr
    finally:
        plant.send_signal(__import__("signal").SIGINT)
        _, err = plant.communicate(timeout=30)
    n = int(err.split(" valve changes")[0].rsplit(", ", 1)[-1])
    assert n > 100, err  # both controllers' 50 Hz rows (each module's change is one event)
    header = (tmp_path / "truth" / "switches.csv").read_text().splitlines()[0]
    assert header == "t_lab," + ",".join(f"d{i}" for i in range(1, 9))
