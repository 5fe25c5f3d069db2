"""A real Vicon Tracker 3 export made by another lab, imported as its maker wrote it.

Source: https://github.com/uncobruce/viconplotter at commit
cd30bc51b1fd4e0cb8d53a200ab22f9b74bcac90, ``vicon_data/QBii_Square_2m_cw.csv`` and
``vicon_data/QBii_Stadium_1m_ccw.csv``: a ground robot ("QBii") driven round a 2 m square
clockwise and a 1 m stadium counter-clockwise (the names say so), 100 Hz. The repository
states no licence, so its files are not in this repository: get them with

    git clone https://github.com/uncobruce/viconplotter && git -C viconplotter checkout cd30bc5
    TPODS_REAL_VICON_TRACKER_DIR=viconplotter/vicon_data pytest tests/regression/test_real_vicon_tracker.py

and the tests below run (skipped otherwise). What they check is what the source states
(a 2 m square, clockwise; a 1 m stadium, counter-clockwise, each driven once round) and
what the files show of themselves (100 Hz frames, every frame kept). Measured on
2026-11-26: the square spans 2.09 x 2.14 m with a net yaw of -360.1 deg, the stadium
1.10 x 2.13 m with +365.0 deg; the angles are helical (max tilt 1.7 deg; read as Euler XYZ
the robot would tilt 136 deg), docs/real-data.md.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from common.csvtable import read_table
from tests.support.cli import run

DIR = os.environ.get("TPODS_REAL_VICON_TRACKER_DIR")
pytestmark = pytest.mark.skipif(not DIR, reason="set TPODS_REAL_VICON_TRACKER_DIR (the file "
                                                "has no licence; see the module doc)")


@pytest.mark.parametrize("name, side_m, turn_deg", [("QBii_Square_2m_cw.csv", (2.0, 2.0), -360.0),
                                                    ("QBii_Stadium_1m_ccw.csv", (1.0, 2.0), 360.0)])
def test_a_real_tracker_export_imports_as_the_source_describes(tpods_exe, tmp_path, name, side_m,
                                                               turn_deg):
    out = tmp_path / "run"
    r = run(tpods_exe, "import", "poses", str(Path(DIR) / name), "--out", str(out))
    assert r.returncode == 0, r.stderr
    meta = json.loads((out / "run.json").read_text())
    assert meta["source"]["format"] == "vicon-tracker-csv"
    assert meta["source"]["body"] == "QBii:QBii" and meta["source"]["rate_hz"] == 100.0
    assert meta["source"]["rotation"].startswith("helical (undeclared")
    assert meta["counts"]["kept"] == meta["counts"]["frames"]
    t, x, y, psi = read_table(out / "poses.csv", ("t", "x", "y", "psi")).T
    assert np.allclose(np.diff(t), 0.01, atol=1e-9)
    span = sorted((np.ptp(x), np.ptp(y)))
    assert np.allclose(span, sorted(side_m), rtol=0.15), span  # driven by hand-tuned control
    yaw = np.unwrap(psi)
    assert abs(np.degrees(yaw[-1] - yaw[0]) - turn_deg) < 20.0
