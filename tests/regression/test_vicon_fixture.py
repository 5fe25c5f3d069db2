"""Regression: the recorded Vicon Tracker capture (runs/fixtures/vicon-tracker/) replayed
through ``--source pcap`` (the Tracker parser), the bridge and the recorder gives the
checked-in golden ``poses.csv`` of each body (same text; else equal to 1e-12 with a
readable diff) and the golden counters (malformed 1, occluded per body, ...).

The goldens move only deliberately: ``python -m tests.support.fixtures_vicon
--goldens-only`` recomputes them from the checked-in capture (and prints the counters);
``git diff runs/fixtures/vicon-tracker/golden`` then shows what moved.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import dpkt
import pytest

from tests.support.fixtures_vicon import BODIES, FIXTURE, PCAP, replay_and_record

TOL = 1e-12
REGENERATE = "python -m tests.support.fixtures_vicon --goldens-only"


def _rows(path: Path) -> tuple[list[str], list[list[float]]]:
    with open(path, newline="") as f:
        r = list(csv.reader(f))
    return r[0], [[float(v) for v in row] for row in r[1:]]


def csv_diff(golden: Path, got: Path, tol: float = TOL, show: int = 8) -> str:
    """'' when ``got`` equals ``golden`` (same text, or every value within ``tol``);
    otherwise a readable account of what moved."""
    if golden.read_text() == got.read_text():
        return ""
    gh, g = _rows(golden)
    hh, h = _rows(got)
    lines = []
    if gh != hh:
        lines.append(f"columns: golden {gh}, got {hh}")
    if len(g) != len(h):
        lines.append(f"rows: golden {len(g)}, got {len(h)}")
    bad = []
    worst = dict.fromkeys(gh, 0.0)
    for i, (a, b) in enumerate(zip(g, h, strict=False)):
        d = [abs(x - y) if math.isfinite(x) and math.isfinite(y) else (0.0 if x == y else math.inf)
             for x, y in zip(a, b, strict=False)]
        for c, v in zip(gh, d, strict=False):
            worst[c] = max(worst[c], v)
        if max(d, default=0.0) > tol:
            bad.append((i, a, b))
    if not bad and not lines:
        return ""
    lines.append(f"{len(bad)} rows differ by more than {tol:g}; largest difference per column: "
                 + ", ".join(f"{c} {v:.3g}" for c, v in worst.items()))
    for i, a, b in bad[:show]:
        lines.append(f"  row {i + 2}: golden {','.join(f'{x:.12g}' for x in a)}")
        lines.append(f"  {' ' * len(str(i + 2))}       got    {','.join(f'{x:.12g}' for x in b)}")
    if len(bad) > show:
        lines.append(f"  ... and {len(bad) - show} more rows")
    return "\n".join(lines)


def test_fixture_is_a_tracker_capture_dpkt_reads():
    """What the fixture claims to be: 301 datagrams padded to 1024 bytes, 2 bodies."""
    with open(FIXTURE / PCAP, "rb") as f:
        recs = [bytes(dpkt.ip.IP(b).udp.data) for _, b in dpkt.pcap.Reader(f)]
    assert len(recs) == 301 and {len(d) for d in recs} == {1024}


@pytest.fixture(scope="module")
def replayed(tmp_path_factory):
    out = tmp_path_factory.mktemp("vicon-fixture") / "rec"
    return out, replay_and_record(FIXTURE / PCAP, out)


@pytest.mark.parametrize("body", BODIES)
def test_replayed_poses_match_the_golden(replayed, body):
    out, _ = replayed
    diff = csv_diff(FIXTURE / "golden" / body / "poses.csv", out / body / "poses.csv")
    assert not diff, (f"{body}/poses.csv moved against runs/fixtures/vicon-tracker/golden:\n{diff}\n"
                      f"(if the change is deliberate: {REGENERATE})")


def test_replayed_counters_match_the_golden(replayed):
    _, counters = replayed
    golden = json.loads((FIXTURE / "golden" / "counters.json").read_text())
    assert counters == golden, (
        f"counters moved: golden {json.dumps(golden, sort_keys=True)}\n"
        f"got {json.dumps(counters, sort_keys=True)}\n(if deliberate: {REGENERATE})")
    assert counters["source"]["malformed"] == 1
    assert {b: c["occluded"] for b, c in counters["bridge"].items()} == {"tpods1": 9, "truss": 13}
    assert counters["recorder"]["recorded"] == 600 - 22


def test_csv_diff_is_readable(tmp_path):
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    a.write_text("t,x,y,psi\n0,1,2,3\n0.01,1.5,2,3\n")
    b.write_text("t,x,y,psi\n0,1,2,3\n0.01,1.5000001,2,3\n")
    d = csv_diff(a, b)
    assert "1 rows differ" in d and "x 1e-07" in d and "row 3" in d
    b.write_text("t,x,y,psi\n0,1,2,3.0000000000000004\n0.01,1.5,2,3\n")
    assert csv_diff(a, b) == ""
