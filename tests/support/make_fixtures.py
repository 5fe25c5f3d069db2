"""Regenerate the curated recorded fixtures under runs/fixtures/.

    python -m tests.support.make_fixtures bench [--out runs/fixtures/bench-session]

``bench``: a short characterisation session (2 nozzle counts x 3 duties) of the emulated
valve controller and OHAUS balance (tests/support/bench.py, served on ptys), both links
captured through the real capture path (``ValveController(capture=)``,
``OhausScout(capture=)``: bench/capture.py). The live session's own results are the
goldens (``golden/steps.csv``, ``golden/thrust_table.toml``: bench.fit order 1). The
recording is kept only if a strict replay (bench/protocol_replay.py) gives exactly those
results; otherwise it is recorded again (a reading landing within microseconds of a
window edge can fall on the other side on replay; see docs/recordings.md).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
from dataclasses import asdict
from pathlib import Path

import numpy as np

from bench.fit import fit_steps
from bench.ohaus.driver import OhausScout
from bench.session import SessionConfig, run_session
from bench.valves import ValveController
from tests.support.bench import Bench

ROOT = Path(__file__).resolve().parents[2]
BENCH_DIR = ROOT / "runs" / "fixtures" / "bench-session"
BENCH_CONFIG = SessionConfig(nozzles=(1, 2), duties_pct=(30, 60, 90), dwell_s=0.3, settle_s=0.1,
                             zero_settle_s=0.1, zero_dwell_s=0.1, watchdog_ms=300)
BENCH_SEED = 19
BENCH_FIT_ORDER = 1  # three duties per nozzle count: a straight line leaves residuals to state

README = """# bench-session: a recorded characterisation session (issue 19)

A short thrust characterisation (nozzles 1 and 2 at 30, 60, 90 % duty; dwell 0.3 s,
settle 0.1 s, zero windows 0.1 + 0.1 s) of the emulated valve controller and OHAUS
balance (tests/support/bench.py, seed {seed}), both serial links captured through the
real capture path: `valves.serial.jsonl`, `scale.serial.jsonl` (format:
docs/recordings.md, "Serial transcripts"); `session.json` is the session's
configuration. `golden/` holds the live session's own results: `steps.csv` and
`thrust_table.toml` (bench.fit, order 1). tests/regression/test_bench_fixture.py
replays both transcripts strictly through the drivers, bench.session and bench.fit and
compares with them (coefficients and thrust columns to 1e-12).

Made by `python -m tests.support.make_fixtures bench` (or `make fixtures`), which keeps a
recording only when its strict replay reproduces the live results exactly.
"""


def replay_session(folder: Path, out: Path, config: SessionConfig):
    with ValveController(f"replay://{folder.resolve()}/valves.serial.jsonl") as valves, \
            OhausScout(f"replay://{folder.resolve()}/scale.serial.jsonl") as scale:
        return run_session(valves, scale, config, out, progress=False)


def same_result(a, b) -> bool:
    cols = ["step", "n_open", "duty_pct", "n", "n_unstable", "mean_raw_gf", "thrust_gf", "drift_gf"]
    if len(a) != len(b):
        return False
    return bool(np.allclose(a[cols].to_numpy(float), b[cols].to_numpy(float), rtol=0, atol=1e-12,
                            equal_nan=True))


def make_bench(out: Path, attempts: int = 8) -> Path:
    for attempt in range(1, attempts + 1):
        with tempfile.TemporaryDirectory() as tmp:
            tmp = Path(tmp)
            rec = tmp / "rec"
            b = Bench(seed=BENCH_SEED)
            try:
                v, s = b.paths
                with ValveController(v, capture=rec / "valves.serial.jsonl") as valves, \
                        OhausScout(s, capture=rec / "scale.serial.jsonl") as scale:
                    live = run_session(valves, scale, BENCH_CONFIG, tmp / "live", progress=False)
            finally:
                b.stop()
            if live.status != "success":
                raise SystemExit(f"the recorded session failed: {live.error}")
            rep = replay_session(rec, tmp / "replay", BENCH_CONFIG)
            if not same_result(live.steps, rep.steps):
                print(f"attempt {attempt}: the strict replay differs at a window edge; recording again",
                      file=sys.stderr)
                continue
            if out.exists():
                shutil.rmtree(out)
            (out / "golden").mkdir(parents=True)
            for name in ("valves.serial.jsonl", "scale.serial.jsonl"):
                shutil.copy(rec / name, out / name)
            (out / "session.json").write_text(json.dumps(
                {"config": asdict(BENCH_CONFIG), "emulator_seed": BENCH_SEED, "fit_order": BENCH_FIT_ORDER}, indent=1) + "\n")
            live.steps.to_csv(out / "golden" / "steps.csv", index=False)
            fit_steps(live.steps, order=BENCH_FIT_ORDER).table(source="runs/fixtures/bench-session").save(out / "golden" / "thrust_table.toml")
            (out / "README.md").write_text(README.format(seed=BENCH_SEED))
            size = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
            print(f"{out}: {size / 1e3:.0f} kB (attempt {attempt})")
            return out
    raise SystemExit(f"no recording replayed exactly in {attempts} attempts")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tests.support.make_fixtures", description=__doc__.split("\n")[0])
    ap.add_argument("which", choices=["bench"])
    ap.add_argument("--out", default=None, help="output folder (default runs/fixtures/bench-session)")
    args = ap.parse_args(argv)
    make_bench(Path(args.out) if args.out else BENCH_DIR)
    return 0


if __name__ == "__main__":
    sys.exit(main())
