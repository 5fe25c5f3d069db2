"""Flights across a lab of network namespaces with a fault injected on the way
(tests/support/lab_net.py, tests/support/lab_flight.py): a 2 s partition of the mocap
host, a router restart, the module host's link cut while the valves are open. The longer
matrix (packet loss, delay and reordering, the estimator's host killed) is in
tests/net/test_lab_faults_slow.py.

After each: every process ends on its own (no manual step), the estimator names every gap
(start, end, poses missing) in its output and its run folder, the recording holds every
pose that reached the estimator's host, and the valves close within the watchdog when the
player's link is gone. Each test writes its outcome to ``lab-faults.jsonl`` in the run's
temporary folder, or ``$TPODS_LAB_REPORT_DIR`` (docs/live.md's fault table is made from
those lines).
"""

from __future__ import annotations

import csv
import json
import math
import os
import time
from pathlib import Path

import pytest

from estimator.live.gaps import gap_warnings
from tests.support import lab_net
from tests.support.lab import TRUTH
from tests.support.lab_flight import FlightResult, LabFlight

pytestmark = [pytest.mark.netns, pytest.mark.flight,
              pytest.mark.skipif(lab_net.refusal() is not None, reason=str(lab_net.refusal()))]

FLIGHT_S = 6.0
FAULT_AT_S = 2.5  # after the player started (it waits for the estimator first: ~1 s)


def poses_csv(r: FlightResult) -> list[float]:
    with (r.live_dir / "poses.csv").open() as fh:
        return [float(row["t"]) for row in csv.DictReader(fh)]


def estimates_csv(r: FlightResult) -> list[dict[str, float]]:
    with (r.live_dir / "estimates.csv").open() as fh:
        return [{k: float(v) for k, v in row.items() if k != "phase"} for row in csv.DictReader(fh)]


def check_whole(r: FlightResult) -> None:
    """Every process ended by itself and cleanly; the recording holds every pose that
    reached the host (none dropped between arrival and poses.csv), and its gaps are in
    gaps.csv and run.json as in the output."""
    assert r.returncodes["play"] == 0, r.stderr["play"]
    assert r.returncodes["live"] == 0, r.stderr["live"]
    assert r.play["status"] == "success"
    assert all(v == 0 for v in r.returncodes.values()), (r.returncodes, r.stderr)
    c = r.summary["counters"]
    rows = poses_csv(r)
    assert len(rows) == c["align_poses_out"] == c["updates"]
    assert (c["align_poses_out"] + c["align_before_first_cmd"] + c["align_occluded"]
            + c["align_duplicates"] + c["align_too_old"] + c["align_non_finite"] + c["pending"]
            + c["clock_overlap_skipped"] == c["poses_rx"])
    run = json.loads((r.live_dir / "run.json").read_text())
    assert run["recorded"]["poses"] == len(rows)
    assert run["final"]["gaps"] == r.summary["gaps"]  # the output's and the recording's
    gaps = r.gaps()  # gaps.csv: all of them
    assert r.summary["gap_count"] == len(gaps)
    key = [(g["stream"], g["before"], g["after"], g["missing"]) for g in gaps]
    assert [(g["stream"], g["before"], g["after"], g["missing"])
            for g in r.summary["gaps"]] == key[:len(r.summary["gaps"])]
    assert r.summary["poses_missing"] == sum(g["missing"] for g in gaps if g["stream"] == "poses")
    for line in gap_warnings(gaps, run["t0_lab"]):  # and in words on stderr
        assert line in r.stderr["live"], line
    # the recording's only holes are the named gaps (by frame number: the vicon-udp bridge
    # stamps a pose with its receive time, so a stalled bridge bunches the times)
    frames = [int(e["frame"]) for e in estimates_csv(r)]
    assert len(frames) == len(rows)
    holes = [(a, b) for a, b in zip(frames, frames[1:], strict=False) if b - a > 1]
    named = [(g["before"], g["after"]) for g in r.gaps() if g["stream"] == "poses"]
    assert all(h in named for h in holes), (holes, named)
    # the module's valves are closed at the end
    assert not any(r.module["changes"][-1]["duties"])


def check_estimate(r: FlightResult, k: float = 4.0) -> tuple[float, float]:
    s = r.summary
    assert not s["diverged"], s
    zm = (s["mass_kg"] - TRUTH.mass_kg) / s["mass_sigma_kg"]
    zi = (s["izz_kgm2"] - TRUTH.izz_kgm2) / s["izz_sigma_kgm2"]
    assert abs(zm) < k and abs(zi) < k, (zm, zi)
    return zm, zi


def record(request, fault: str, r: FlightResult, **outcome) -> None:
    """One line of the fault table (docs/live.md) in the run's temporary folder."""
    s = r.summary
    line = {"fault": fault, "test": request.node.name, "mass_z": outcome.pop("zm", None),
            "izz_z": outcome.pop("zi", None), "poses_rx": s["counters"]["poses_rx"],
            "poses_emitted": r.module.get("frames"), "gaps": r.gaps(), **outcome}
    base = request.config._tmp_path_factory.getbasetemp()
    if hasattr(request.config, "workerinput"):  # an xdist worker's: the run's is above it
        base = base.parent
    folder = Path(os.environ.get("TPODS_LAB_REPORT_DIR") or base)
    folder.mkdir(parents=True, exist_ok=True)
    with (folder / "lab-faults.jsonl").open("a") as fh:
        fh.write(json.dumps(line) + "\n")


def test_partition_of_the_mocap_host_loses_no_pose_and_names_the_pause(tmp_path, request):
    """The mocap host's lab link down for 2 s: TCP holds the poses and delivers them after
    the heal; the estimator names the 2 s pause (none missing), uses every pose, and the
    first pose after it arrives within 1 s of the heal."""
    with lab_net.lab_net() as lab:
        flight = LabFlight(lab, tmp_path)
        flight.start_all(FLIGHT_S)
        time.sleep(FAULT_AT_S)
        lab.partition("mocap", 2.0).join()
        t_up = lab.events[-1][0]
        r = flight.collect()
    check_whole(r)
    zm, zi = check_estimate(r)
    (g,) = [g for g in r.gaps() if g["stream"] == "poses"]
    assert g["missing"] == 0  # the link held them
    assert 1.5 < g["silent_s"] < 4.0
    recovery = g["host_end"] - t_up
    assert recovery < 1.0
    assert not [g for g in r.gaps() if g["stream"] == "commands"]  # the player's host was fine
    record(request, "mocap host partitioned 2 s (ip link down)", r, zm=zm, zi=zi,
           recovery_s=recovery, recovery_from="the link came up",
           held=f"all poses (TCP replay, {g['silent_s']:.2f} s late)")


def test_router_restart_every_process_reconnects_and_the_gap_is_named(tmp_path, request):
    """The router stopped and started again 0.5 s later: every client reconnects on its
    own, the poses and commands lost meanwhile are named (start, end, how many), the filter
    forgets the motion across the unknown input (its sigma grows) and is back within 1 s."""
    with lab_net.lab_net() as lab:
        flight = LabFlight(lab, tmp_path)
        flight.start_all(FLIGHT_S)
        time.sleep(FAULT_AT_S)
        t_start = flight.restart_router(0.5)
        r = flight.collect()
    check_whole(r)
    zm, zi = check_estimate(r)
    assert r.stderr["router2"].count("joined") >= 3  # bridge, estimator, player
    (gp,) = [g for g in r.gaps() if g["stream"] == "poses"]
    (gc,) = [g for g in r.gaps() if g["stream"] == "commands"]
    assert gp["missing"] > 0 and gc["missing"] > 0
    # frames accounted for: received + missing = the span of frames seen
    c = r.summary["counters"]
    assert gp["after"] - gp["before"] - 1 == gp["missing"]
    recovery = gp["host_end"] - t_start
    assert recovery < 5.0
    # the filter's position sigma grows across the gap and is back within 1 s after it
    est = estimates_csv(r)
    t0 = json.loads((r.live_dir / "run.json").read_text())["t0_lab"]
    before = [e for e in est if e["t"] + t0 <= gp["t_start"]][-1]
    after = [e for e in est if e["t"] + t0 >= gp["t_end"]]
    # (the rows of the first poses after the gap may be written before the command that
    # reveals the lost input arrives; the filter then re-runs from before the gap)
    soon = [e for e in after if e["t"] + t0 < gp["t_end"] + 0.2]
    peak = max(range(len(soon)), key=lambda i: soon[i]["sigma_u"])
    assert soon[peak]["sigma_u"] > 3 * before["sigma_u"]
    back = [e for e in after[peak:] if e["sigma_u"] < 2 * before["sigma_u"]]
    assert back and back[0]["t"] + t0 - gp["t_end"] < 1.0
    assert c["motion_resets"] >= 1
    record(request, "router restarted (stopped, started 0.5 s later)", r, zm=zm, zi=zi,
           recovery_s=recovery, recovery_from="the new router process started",
           filter_back_s=back[0]["t"] + t0 - gp["t_end"],
           held=f"poses and commands before and after; {gp['missing']} poses and "
                f"{gc['missing']} commands lost while no router ran")


def test_module_link_cut_while_valves_open_closes_them_within_the_watchdog(tmp_path, request):
    """The module host's lab link down while the valves are open: the player's socket://
    link is gone, its watchdog feeds stop reaching the controller, and the controller closes
    every valve within the watchdog (500 ms); the player stops with an error, says so, and
    its end still reaches the estimator."""
    with lab_net.lab_net() as lab:
        flight = LabFlight(lab, tmp_path)
        flight.start_all(FLIGHT_S)
        time.sleep(FAULT_AT_S)
        lab.link("module", False)
        t_cut = lab.events[-1][0]
        rc = flight.wait("play", 20.0)
        lab.link("module", True)
        r = flight.collect()
    assert rc not in (0, None), r.stderr["play"]
    assert "Traceback" not in r.stderr["play"]
    changes = r.module["changes"]
    wd = [c for c in changes if c["cause"] == "watchdog"]
    assert wd and not any(wd[0]["duties"]), changes[-3:]
    i = changes.index(wd[0])
    assert any(changes[i - 1]["duties"])  # open until the watchdog closed them
    closed_after = wd[0]["t_wall"] - t_cut
    assert closed_after <= 0.5 + 0.05, closed_after
    assert all(not any(c["duties"]) for c in changes[i:])  # nobody opened them again
    assert r.returncodes["live"] == 0, r.stderr["live"]
    record(request, "module host link cut while valves open", r,
           valves_closed_after_s=closed_after,
           held=f"valves closed by the controller watchdog {closed_after * 1e3:.0f} ms after "
                f"the cut; player exit {rc}")
    assert math.isfinite(closed_after)
