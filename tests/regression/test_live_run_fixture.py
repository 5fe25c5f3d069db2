"""Regression: the recorded live run (runs/fixtures/live-run/).

- Batch LS on its run folder (``tpods estimate batch --json``) gives the golden mass, Izz
  and sigmas (rel. 1e-9).
- Its MCAP replayed onto Zenoh (``tpods replay --speed 2``) into ``tpods estimate live
  --method ekf`` gives the golden final estimate (rel. 1e-9: the replays gave the same bits
  every time; see tests/support/replay_live.py for why not ``--speed 0``), which is also
  the last row of the ``estimates.csv`` the live estimator recorded (to its printed digits).
"""

import json

import pandas as pd

from common.mcap.log import read_mcap
from tests.support import golden
from tests.support.cli import run_in_process
from tests.support.replay_live import replay_final_estimate
from tpods.fixtures import FIXTURES_ROOT, golden_path, replay_golden_path

FIXTURE = FIXTURES_ROOT / "live-run"


def test_batch_ls_on_the_run_folder_gives_its_golden(tpods_exe):
    r = run_in_process("estimate", "batch", str(FIXTURE), "--json")
    assert r.returncode == 0, r.stderr
    est = json.loads(r.stdout)
    golden.check_values({k: est[k] for k in ("mass_kg", "mass_sigma_kg", "izz_kgm2", "izz_sigma_kgm2")},
                        golden_path(FIXTURE), atol=0.0, rtol=1e-9, what="batch LS on the live run")


def test_the_mcap_replayed_into_the_live_estimator_gives_the_recorded_final_estimate():
    rec = read_mcap(FIXTURE / "recording.mcap")
    assert rec.complete
    est = replay_final_estimate(FIXTURE / "recording.mcap")
    golden.check_values(est, replay_golden_path(FIXTURE), atol=0.0, rtol=1e-9,
                        what="the live estimator fed by tpods replay")
    last = pd.read_csv(FIXTURE / "estimates.csv").iloc[-1]
    assert len(pd.read_csv(FIXTURE / "estimates.csv")) == est["n_updates"]
    for k, rel in (("mass_kg", 1e-8), ("izz_kgm2", 1e-8), ("mass_sigma_kg", 1e-5), ("izz_sigma_kgm2", 1e-5)):
        assert abs(est[k] - last[k]) <= rel * abs(last[k]), (k, est[k], last[k])
