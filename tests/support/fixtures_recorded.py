"""Record the live-run, bifilar-swing and structure-run fixtures under runs/fixtures/ again.

    python -m tests.support.fixtures_recorded live-run|bifilar-swing|structure-run|all [--root DIR]

Each is made through the real recording path against the project's simulated lab, then its
goldens are computed with :func:`tpods.fixtures.write_goldens` (the functions the
regression tests and ``tpods fixture add`` use):

- ``live-run``: :func:`record_live_run`: a simulated module (:class:`tpods.plant_loop.SimulatedModule`,
  60 Hz poses, 1 cm / 1 deg noise) in this process, ``tpods run play`` (phase-sine, 10 s of
  lab time at time scale 2) and ``tpods estimate live --method ekf --out DIR --mcap``
  as subprocesses over a private loopback Zenoh endpoint (as tpods/demo/stages.py
  stage_run does); the live estimator's run folder and ``recording.mcap`` are kept.
- ``bifilar-swing``: :func:`record_bifilar`: a bifilar swing simulated by
  :func:`calibration.swing.bifilar.simulate_trace` (the trace of
  :func:`calibration.swing.bifilar.swing_and_estimate`) as ``poses.csv`` + ``bifilar.json``
  (the inputs of ``tpods calibrate bifilar``).
- ``structure-run``: :func:`record_structure`: ``tpods sim --structure structure.toml
  --duration 30`` (two modules); ``truth.csv`` is left out to keep the fixture small.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from tpods.fixtures import FIXTURES_ROOT, write_fixture_json, write_goldens

LIVE_DURATION_S = 10.0
LIVE_SCALE = 2.0
LIVE_SEED = 19
LIVE_POSE_RATE = 60.0

BIFILAR = {"mass_kg": 0.72, "spacing_m": 0.10, "length_m": 1.0, "u_mass_kg": 1.44e-3,
           "u_spacing_m": 5e-4, "u_length_m": 2e-3}
BIFILAR_TRUTH_IZZ = 1.2e-3
BIFILAR_SIM = {"release_deg": 20.0, "duration_s": 20.0, "rate_hz": 100.0, "noise_deg": 1.0, "seed": 19}

STRUCTURE_TOML = """\
# Two TPODS modules on one rigid body (the structure of tests/tpods/cli/test_estimate_structure.py)
name = "truss"
[[modules]]
name = "tpods1"
position_m = [-0.2, 0.0]
yaw_deg = 0
[[modules]]
name = "tpods2"
position_m = [0.2, 0.05]
yaw_deg = 90
"""
# the truth as sim options, not as [body] values: a [body] value without a sigma is known to
# tpods estimate (fixed), so the run's structure.toml carries none (everything estimated)
STRUCTURE_ARGS = ["--mass", "1.6", "--izz", "0.03", "--com", "0.03,0", "--duration", "30",
                  "--pose-rate", "60", "--cmd-rate", "25", "--seed", "19"]


def _tpods() -> str:
    exe = Path(sys.executable).with_name("tpods")
    return str(exe) if exe.exists() else shutil.which("tpods")


def _readme(out: Path, title: str, body: str) -> None:
    (out / "README.md").write_text(f"# {out.name}: {title}\n\n{body.strip()}\n")


def record_live_run(out: Path) -> dict:
    """A live run recorded by ``tpods estimate live --out DIR --mcap`` while a simulated
    module plays; returns the live estimator's final summary (its ``--json`` line)."""
    from common.thrust_table import ThrustTable
    from estimator.plant.model import PlantParams
    from tests.support.lab import loopback_peers
    from tests.support.net import matching, wait_for
    from tpods.clock import LabClock
    from tpods.plant_loop import MocapNoise, SimulatedModule
    from tpods.player import cmd_key

    exe = _tpods()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        with loopback_peers(1) as (ep, (a,)):
            clock = LabClock(LIVE_SCALE, time.time())
            zargs = ["--connect", ep, "--no-multicast"]
            with SimulatedModule(a, PlantParams(2.268, 3.78e-3), ThrustTable.default(), clock=clock,
                                 pose_rate_hz=LIVE_POSE_RATE, noise=MocapNoise(0.01, math.radians(1.0)),
                                 seed=LIVE_SEED) as module:
                live = subprocess.Popen([exe, "estimate", "live", "--method", "ekf", "--out",
                                         str(tmp / "live"), "--mcap", "--exit-on-end", "--json",
                                         "--quiet", *zargs],
                                        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
                try:
                    probe = a.declare_publisher(cmd_key("tpods1"))
                    if not wait_for(lambda: matching(probe) or live.poll() is not None, 60.0):
                        raise SystemExit("the live estimator did not subscribe")
                    probe.undeclare()
                    time.sleep(0.3)
                    play = subprocess.run(
                        [exe, "run", "play", "--valves", module.valves_path, "--input", "phase-sine",
                         "--duration", f"{LIVE_DURATION_S:g}", "--cmd-rate", "25", "--out", str(tmp / "play"),
                         "--time-scale", f"{LIVE_SCALE:g}", "--clock-origin", repr(clock.origin),
                         "--no-progress", *zargs], capture_output=True, text=True, timeout=300)
                    if play.returncode != 0:
                        raise SystemExit(f"tpods run play failed: {play.stderr}")
                    stdout, stderr = live.communicate(timeout=120)
                finally:
                    if live.poll() is None:
                        live.kill()
                if live.returncode != 0:
                    raise SystemExit(f"tpods estimate live failed: {stderr}")
        if out.exists():
            shutil.rmtree(out)
        shutil.copytree(tmp / "live", out)
    summary = json.loads(stdout.strip().splitlines()[-1])
    _readme(out, "a live run with its Zenoh streams in MCAP (issue 19)", f"""
A short live run: the simulated module (tpods.plant_loop.SimulatedModule: m = 2.268 kg,
Izz = 3.78e-3 kg m^2, the paper's Table 2, poses at {LIVE_POSE_RATE:g} Hz with 1 cm / 1 deg
noise, seed {LIVE_SEED}) driven by `tpods run play --input phase-sine --cmd-rate 25 --duration
{LIVE_DURATION_S:g} --time-scale {LIVE_SCALE:g}`, estimated and recorded by `tpods estimate live
--method ekf --out DIR --mcap --exit-on-end` over a private loopback Zenoh endpoint: the
run folder the live estimator wrote (`commands.csv`, `poses.csv`, `estimates.csv`,
`estimate.json`, `run.json`) and `recording.mcap` (its pose, command and estimate streams).

Goldens: `golden/values.json` (batch LS on the run folder, `tpods estimate batch`: mass,
izz and their sigmas, rel. 1e-9) and `golden/replay.json` (the final estimate of `tpods
estimate live --method ekf --max-wait-ms 20` fed by `tpods replay recording.mcap --speed 4`:
mass, izz, sigmas, updates, rel. 1e-9; tests/regression/test_live_run_fixture.py, which also
checks it against the last row of the recorded `estimates.csv`, to its 10 printed digits).
Replays gave the same bits every time, equal to the recorded final estimate (here also
`estimate.json`, the live summary; in an earlier recording that summary had been taken one
update before the end, 0.08 sigma away in mass, so the test compares with `estimates.csv`).

Made by `python -m tests.support.fixtures_recorded live-run` (tests/support/fixtures_recorded.py,
`record_live_run`; `make fixtures` remakes every fixture).
""")
    write_fixture_json(out, "run", source="tpods estimate live --out DIR --mcap (simulated module)",
                       how="python -m tests.support.fixtures_recorded live-run")
    return summary


def record_bifilar(out: Path) -> Path:
    """An emulated bifilar swing as ``poses.csv`` (t, x, y, psi) + ``bifilar.json``."""
    import numpy as np

    from calibration.swing.bifilar import Pendulum, simulate_trace

    p = Pendulum(BIFILAR["mass_kg"], BIFILAR_TRUTH_IZZ, BIFILAR["spacing_m"], BIFILAR["length_m"],
                 c1=0.004, c2=0.01)
    t, psi = simulate_trace(p, **BIFILAR_SIM)
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    np.savetxt(out / "poses.csv", np.column_stack([t, np.zeros_like(t), np.zeros_like(t), psi]),
               delimiter=",", header="t,x,y,psi", comments="", fmt="%.9g")
    (out / "bifilar.json").write_text(json.dumps(BIFILAR, indent=1) + "\n")
    d = BIFILAR
    _readme(out, "an emulated bifilar swing (issue 19)", f"""
A bifilar swing of a body with m = {d['mass_kg']} kg, Izz = {BIFILAR_TRUTH_IZZ} kg m^2 (truth) on
strings D = {d['spacing_m']} m apart, h = {d['length_m']} m long, released from
{BIFILAR_SIM['release_deg']:g} deg, {BIFILAR_SIM['duration_s']:g} s of mocap yaw at
{BIFILAR_SIM['rate_hz']:g} Hz with {BIFILAR_SIM['noise_deg']:g} deg noise (seed
{BIFILAR_SIM['seed']}; viscous c1 = 0.004, quadratic c2 = 0.01): `poses.csv` (t, x, y, psi in
rad) from `calibration.swing.bifilar.simulate_trace` (the trace `swing_and_estimate` fits) and
`bifilar.json`, the other inputs of `tpods calibrate bifilar`.

Golden: `golden/values.json`, Izz and its sigma of `tpods calibrate bifilar --poses .
--mass {d['mass_kg']} --spacing {d['spacing_m']} --length {d['length_m']} --u-mass
{d['u_mass_kg']} --u-spacing {d['u_spacing_m']} --u-length {d['u_length_m']} --json` (rel. 1e-9).

Made by `python -m tests.support.fixtures_recorded bifilar-swing`
(tests/support/fixtures_recorded.py, `record_bifilar`).
""")
    write_fixture_json(out, "bifilar", source="calibration.swing.bifilar.simulate_trace",
                       how="python -m tests.support.fixtures_recorded bifilar-swing")
    return out


def record_structure(out: Path) -> Path:
    """``tpods sim --structure structure.toml --duration 30`` of two modules."""
    with tempfile.TemporaryDirectory() as tmp:
        toml = Path(tmp) / "structure.toml"
        toml.write_text(STRUCTURE_TOML)
        r = subprocess.run([_tpods(), "sim", "--structure", str(toml), *STRUCTURE_ARGS, "--out",
                            str(Path(tmp) / "run")], capture_output=True, text=True, timeout=120)
        if r.returncode != 0:
            raise SystemExit(f"tpods sim failed: {r.stderr}")
        if out.exists():
            shutil.rmtree(out)
        shutil.copytree(Path(tmp) / "run", out)
    (out / "truth.csv").unlink()
    _readme(out, "a two-module structure run (issue 18, 19)", f"""
Two modules on one rigid body (m = 1.6 kg, Izz = 0.03 kg m^2, centre of mass (0.03, 0) m
in the tracked frame), simulated by `tpods sim --structure structure.toml
{' '.join(STRUCTURE_ARGS)}` (phase-sine on all 8 valves): `commands.csv` (t, d1..d8),
`poses.csv`, `run.json`, `structure.toml`; `truth.csv` is left out (it would double the size;
the truth is in run.json).

`structure.toml` has no `[body]` table: the truth is given with `--mass`, `--izz`, `--com`,
not as `[body]` values, because `tpods estimate` takes a `[body]` value without a sigma as
known (fixed) and one with a sigma as a prior; here mass, Izz and the centre of mass are all
estimated. (Until issue 18's partly-known properties landed, `[body]` held the truth and was
only the estimator's start; the simulated data are the same bits.)

Golden: `golden/values.json`, `tpods estimate batch RUN --json`: mass, izz, com_x_m, com_y_m
and their sigmas (rel. 1e-9).

Made by `python -m tests.support.fixtures_recorded structure-run`
(tests/support/fixtures_recorded.py, `record_structure`).
""")
    write_fixture_json(out, "structure-run", source="tpods sim --structure",
                       how="python -m tests.support.fixtures_recorded structure-run")
    return out


def write_live_replay_golden(out: Path) -> str:
    """``golden/replay.json``: the MCAP replayed into ``tpods estimate live``."""
    from tests.support.replay_live import replay_final_estimate
    from tpods.fixtures import replay_golden_path

    values = replay_final_estimate(out / "recording.mcap")
    replay_golden_path(out).write_text(json.dumps(values, indent=1, sort_keys=True) + "\n")
    return f"golden {replay_golden_path(out)}: written"


MAKERS = {"live-run": record_live_run, "bifilar-swing": record_bifilar, "structure-run": record_structure}


def make(name: str, root: Path = FIXTURES_ROOT) -> Path:
    out = root / name
    MAKERS[name](out)
    for line in write_goldens(out):
        print(line)
    if name == "live-run":
        print(write_live_replay_golden(out))
    size = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    print(f"{out}: {size / 1e3:.0f} kB")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tests.support.fixtures_recorded",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("which", choices=[*MAKERS, "all"])
    ap.add_argument("--root", default=str(FIXTURES_ROOT), help="fixtures folder (default runs/fixtures)")
    args = ap.parse_args(argv)
    for name in (MAKERS if args.which == "all" else [args.which]):
        make(name, Path(args.root))
    return 0


if __name__ == "__main__":
    sys.exit(main())
