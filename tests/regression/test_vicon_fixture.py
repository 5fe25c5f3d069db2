"""Regression: the recorded Vicon Tracker capture (runs/fixtures/vicon-tracker/) replayed
through ``--source pcap`` (the Tracker parser), the bridge and the recorder gives the
checked-in golden ``poses.csv`` of each body (to 1e-12) and the golden counters exactly
(malformed 1, occluded per body, poses recorded, ...).

A changed result fails with the rows and values that moved (tests/support/golden.py).
Deliberate changes: ``make golden`` (``pytest tests/regression --update-goldens``) or
``python -m tests.support.fixtures_vicon --goldens-only`` rewrite the goldens and print
what moved; ``python -m tests.support.fixtures_vicon`` records the capture again.
"""

from __future__ import annotations

import dpkt
import pytest

from tests.support.fixtures_vicon import FIXTURE, PCAP, check_goldens, replay_and_record


def test_fixture_is_a_tracker_capture_dpkt_reads():
    """What the fixture claims to be: 301 datagrams padded to 1024 bytes, from one port
    to Tracker's."""
    with open(FIXTURE / PCAP, "rb") as f:
        recs = [dpkt.ip.IP(b).udp for _, b in dpkt.pcap.Reader(f)]
    assert len(recs) == 301 and {len(u.data) for u in recs} == {1024}
    assert len({(u.sport, u.dport) for u in recs}) == 1


@pytest.fixture(scope="module")
def replayed(tmp_path_factory):
    out = tmp_path_factory.mktemp("vicon-fixture") / "rec"
    return out, replay_and_record(FIXTURE / PCAP, out)


def test_replay_through_bridge_and_recorder_matches_the_goldens(replayed):
    out, counters = replayed
    check_goldens(out, counters)


def test_the_counters_say_what_the_fixture_holds(replayed):
    _, c = replayed
    assert c["source"]["malformed"] == 1 and c["source"]["datagrams"] == 301
    assert {b: v["occluded"] for b, v in c["bridge"].items()} == {"tpods1": 9, "truss": 13}
    assert c["recorder"]["recorded"] == 600 - 22 and c["recorder"]["not_increasing"] == 0
