"""The longer fault matrix across a lab of namespaces (``make test-slow``): 5 % packet loss
with nftables, 50 +- 20 ms delay through a user-space relay (a TCP link: bunched, in order;
the Vicon UDP link: reordered), the estimator's host process killed and a new one started.
The checks are those of tests/net/test_lab_faults.py."""

from __future__ import annotations

import time

import pytest

from tests.net.test_lab_faults import FLIGHT_S, check_estimate, check_whole, record
from tests.support import lab_net
from tests.support.lab_flight import CAMERA_ADDR, LAN_ADDR, MOCAP_UDP_PORT, LabFlight

pytestmark = [pytest.mark.netns, pytest.mark.flight, pytest.mark.slow,
              pytest.mark.skipif(lab_net.refusal() is not None, reason=str(lab_net.refusal()))]


def test_no_fault_the_reference_flight(tmp_path, request):
    """The same flight with no fault: the reference for the table's errors."""
    with lab_net.lab_net() as lab:
        flight = LabFlight(lab, tmp_path)
        flight.start_all(FLIGHT_S)
        r = flight.collect()
    check_whole(r)
    zm, zi = check_estimate(r)
    assert not r.gaps()
    assert abs(r.summary["clock_offset_ms"]) < 2.0  # one kernel clock: none
    record(request, "none (reference flight)", r, zm=zm, zi=zi, held="everything",
           clock_offset_ms=r.summary["clock_offset_ms"])


def test_mocap_clock_20_ms_behind_is_measured_within_2_ms(tmp_path, request):
    """The mocap host's clock 20 ms behind the player's (simulated: the bridge takes 20 ms
    off every pose stamp, ``--latency-ms 20``; the namespaces share one kernel clock):
    the estimator measures -20 ms within 2 ms from the streams' delays and warns."""
    with lab_net.lab_net() as lab:
        flight = LabFlight(lab, tmp_path)
        flight.start_all(FLIGHT_S, bridge={"extra": ("--latency-ms", "20")})
        r = flight.collect()
    check_whole(r)
    s = r.summary
    assert abs(s["clock_offset_ms"] + 20.0) < 2.0, s["clock_offset_ms"]
    assert s["clock_offset_windows"] >= 3 and s["clock_offset_sigma_ms"] < 2.0
    assert "clocks differ by -" in r.stderr["live"]
    record(request, "mocap clock 20 ms behind the player's (simulated)", r,
           held=f"measured {s['clock_offset_ms']:+.2f} +/- {s['clock_offset_sigma_ms']:.2f} ms",
           clock_offset_ms=s["clock_offset_ms"],
           zm=(s["mass_kg"] - 2.268) / s["mass_sigma_kg"],
           zi=(s["izz_kgm2"] - 3.78e-3) / s["izz_sigma_kgm2"])


@pytest.mark.skipif(lab_net.nft_refusal() is not None, reason=str(lab_net.nft_refusal()))
def test_five_percent_loss_on_the_mocap_and_router_hosts(tmp_path, request):
    """nftables drops 5 % of the packets in and out of the mocap and the router hosts for
    the whole flight (every Zenoh message crosses the router: poses twice, commands once;
    the player's valve link does not): TCP retransmits, no pose is missing, the estimate is
    as good. (The same loss on the player's own host also delays its socket:// valve link
    by retransmissions: valve switches 0.2 s and more after the player's stamps, a timing
    error no estimator can tell from the physics: docs/live.md.)"""
    with lab_net.lab_net() as lab:
        flight = LabFlight(lab, tmp_path)
        flight.start_router()
        lab.loss("mocap", 5)
        lab.loss("router", 5)
        flight.start_module()
        flight.start_bridge()
        flight.start_estimator()
        flight.start_player(FLIGHT_S)
        r = flight.collect()
        dropped = lab.counters("mocap")
    check_whole(r)
    zm, zi = check_estimate(r)
    assert "packets" in dropped
    missing = sum(g["missing"] for g in r.gaps() if g["stream"] == "poses")
    assert missing == 0
    late = max((g["silent_s"] for g in r.gaps()), default=0.0)
    record(request, "5 % loss on the mocap and router hosts (nftables)", r, zm=zm, zi=zi,
           held="all poses and commands (TCP retransmits)",
           longest_pause_s=late)


def test_delay_50_20_ms_on_the_mocap_hosts_zenoh_link(tmp_path, request):
    """The bridge's Zenoh link through a relay holding each chunk 50 +- 20 ms (in order, a
    byte stream): the poses arrive later; the commands still arrive first, so every pose is
    aligned with its command and the estimate is as good. Any pose lost is named."""
    with lab_net.lab_net() as lab:
        flight = LabFlight(lab, tmp_path)
        flight.start_router()
        flight.start_relay("mocap", "tcp", "127.0.0.1:7448", f"{LAN_ADDR['router']}:7447")
        flight.start_module()
        flight.start_bridge(connect="tcp/127.0.0.1:7448")
        flight.start_estimator()
        flight.start_player(FLIGHT_S)
        r = flight.collect()
    check_whole(r)  # (every hole named)
    zm, zi = check_estimate(r)
    # seen once in five runs: 9 poses (0.1 s) the bridge published while the player's
    # session joined the router never reached the estimator; named as a gap
    missing = sum(g["missing"] for g in r.gaps())
    assert missing <= 25
    assert r.relays["relay-tcp"]["sent"] > 100
    record(request, "50 +- 20 ms delay on the mocap host's Zenoh link (TCP relay)", r, zm=zm,
           zi=zi, held="all poses, in order (bunched by the jitter)" if not missing else
           f"poses in order, but {missing} published as the player joined never arrived")


def test_delay_and_reordering_on_the_camera_link(tmp_path, request):
    """The Vicon datagrams through a relay holding each one 50 +- 20 ms on its own, so they
    reorder: the bridge drops a frame older than one it published, and the estimator names
    each such hole (frames missing) instead of bridging it."""
    relay_port = MOCAP_UDP_PORT + 1
    with lab_net.lab_net() as lab:
        flight = LabFlight(lab, tmp_path)
        flight.start_router()
        flight.start_relay("mocap", "udp", f"{CAMERA_ADDR['mocap']}:{MOCAP_UDP_PORT}",
                           f"127.0.0.1:{relay_port}")
        flight.start_module()
        flight.start_bridge(bind="127.0.0.1", port=relay_port)
        flight.start_estimator()
        flight.start_player(FLIGHT_S)
        r = flight.collect()
    check_whole(r)
    assert r.relays["relay-udp"]["reordered"] > 0
    missing = sum(g["missing"] for g in r.gaps() if g["stream"] == "poses")
    assert missing > 0  # the reordered frames the bridge dropped, named
    s = r.summary
    record(request, "50 +- 20 ms delay with reordering on the camera link (UDP relay)", r,
           zm=(s["mass_kg"] - 2.268) / s["mass_sigma_kg"],
           zi=(s["izz_kgm2"] - 3.78e-3) / s["izz_sigma_kgm2"],
           held=f"{r.relays['relay-udp']['reordered']} datagrams reordered; the bridge kept "
                f"the newer, {missing} older frames named missing")


def test_estimator_killed_and_a_new_one_resumes(tmp_path, request):
    """The estimator's process killed (SIGKILL) mid-flight and a new one started 1 s later
    with ``--resume`` on the dead one's folder: the dead folder holds every pose it had
    covered by a command (status ``running`` left behind); the new folder holds those once
    and then the live ones, the time it was down is a named gap, and the estimate is
    within 5 sigma of the truth."""
    import csv
    import json
    import signal

    with lab_net.lab_net() as lab:
        flight = LabFlight(lab, tmp_path)
        # longer than the others: the EKF from the far start needs some seconds on each side
        # of the restart (with 1.3 s before it and 4 s after, Izz was off by 6.9 sigma once)
        flight.start_all(FLIGHT_S + 4.0)
        time.sleep(4.0)
        lab.stop(flight.procs["live"], sig=signal.SIGKILL)
        t_kill = time.time()
        time.sleep(1.0)
        flight.start_estimator(name="live2", out="live2",
                               extra=("--resume", str(tmp_path / "live")))
        r2 = flight.collect(live="live2")
    first = json.loads((tmp_path / "live" / "run.json").read_text())
    assert first["status"] == "running"  # the process died
    second = json.loads((tmp_path / "live2" / "run.json").read_text())
    t0a, t0b = first["t0_lab"], second["t0_lab"]
    ta = [float(x["t"]) + t0a for x in csv.DictReader((tmp_path / "live" / "poses.csv").open())]
    tb = [float(x["t"]) + t0b for x in csv.DictReader((tmp_path / "live2" / "poses.csv").open())]
    assert ta and tb[:len(ta)] == pytest.approx(ta, abs=1e-6)  # the dead run's, once each
    assert all(y > x for x, y in zip(tb, tb[1:], strict=False))  # none twice
    assert t_kill - ta[-1] < 0.5  # the dead folder lost at most the last command's span
    assert second["replayed_poses"] == len(ta)
    assert r2.returncodes["live2"] == 0 and r2.play["status"] == "success", r2.stderr["live2"]
    gaps = {g["stream"]: g for g in r2.gaps()}
    assert set(gaps) == {"poses", "commands"}
    assert gaps["poses"]["t_start"] == pytest.approx(ta[-1], abs=1e-6)
    # 5 sigma: the plain EKF from the paper's far start is biased in Izz already (+2 sigma
    # in the 6 s reference flight, more as its sigma shrinks on this 10 s one: +1.2 and
    # +4.2 sigma in two runs), the restart apart
    zm, zi = check_estimate(r2, k=5.0)
    down = gaps["poses"]["t_end"] - gaps["poses"]["t_start"]
    record(request, "estimator process killed (SIGKILL), a new one resumed 1 s later", r2,
           zm=zm, zi=zi, restart_gap_s=down,
           held=f"the dead folder's {len(ta)} poses, taken in again once; "
                f"{gaps['poses']['missing']} poses missed while down, named")
