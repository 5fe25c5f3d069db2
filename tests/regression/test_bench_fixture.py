"""Regression: the recorded characterisation session (runs/fixtures/bench-session) replayed
strictly through today's drivers, bench.session and bench.fit gives its golden steps and
thrust table (issue 19). Regenerate the goldens deliberately with ``--update-goldens``."""

import json
from pathlib import Path

from bench.fit import fit_steps
from bench.session import SessionConfig
from common.thrust_table import ThrustTable
from tests.support import golden
from tests.support.make_fixtures import BENCH_DIR, replay_session

# The session's t = 0 is the host's clock when run_session starts, not a recorded
# event: times move by the replay's start-up (< 10 ms); every value computed from the
# readings is held to 1e-12.
TIME_COLUMNS = {"t_start_s": 0.01, "t_end_s": 0.01}


def _config() -> tuple[SessionConfig, int]:
    meta = json.loads((BENCH_DIR / "session.json").read_text())
    c = meta["config"]
    c = {k: tuple(v) if isinstance(v, list) else v for k, v in c.items()}
    return SessionConfig(**c), int(meta["fit_order"])


def _check_table(table: ThrustTable, path: Path) -> None:
    coeffs = {f"nozzles {k} coefficients": list(table.coefficients[k]) for k in sorted(table.coefficients)}
    if golden.UPDATE["on"]:
        old = ThrustTable.load(path) if path.exists() else None
        moved = ["(new)"] if old is None else golden._value_diffs(
            {f"nozzles {k} coefficients": list(old.coefficients[k]) for k in sorted(old.coefficients)},
            coeffs, 1e-12, 0.0)
        if moved:
            table.save(path)
        print(f"golden {path}: " + ("unchanged" if not moved else "moved:\n  " + "\n  ".join(moved)))
        return
    gold = ThrustTable.load(path)
    problems = golden._value_diffs(
        {f"nozzles {k} coefficients": list(gold.coefficients[k]) for k in sorted(gold.coefficients)},
        coeffs, 1e-12, 0.0)
    if problems:
        raise golden.GoldenMismatch(f"thrust table differs from its golden {path}:\n  " + "\n  ".join(problems)
                                    + "\n(if the change is intended: pytest --update-goldens, or make golden)")


def test_recorded_session_replays_to_its_golden_steps_and_thrust_table(tmp_path):
    config, order = _config()
    res = replay_session(BENCH_DIR, tmp_path / "replay", config)
    assert res.status == "success", res.error
    golden.check_frame(res.steps, BENCH_DIR / "golden" / "steps.csv", atol=1e-12,
                       atol_columns=TIME_COLUMNS, what="steps of the replayed session")
    table = fit_steps(res.steps, order=order).table(source="runs/fixtures/bench-session")
    _check_table(table, BENCH_DIR / "golden" / "thrust_table.toml")


def test_the_fixture_is_small():
    size = sum(p.stat().st_size for p in BENCH_DIR.rglob("*") if p.is_file())
    assert size < 1_000_000, size
    assert (BENCH_DIR / "README.md").read_text().startswith("# bench-session")
