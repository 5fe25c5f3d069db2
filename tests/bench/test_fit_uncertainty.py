"""What `bench fit` states about its table's uncertainty (issue 17, item 1)."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from bench.fit import readability_g, table_uncertainty
from common.thrust_table import ThrustTable
from tpods.cli import main


@pytest.mark.parametrize("d", [0.01, 0.1, 0.002, 0.5])
def test_readability_is_read_from_quantised_readings(d):
    rng = np.random.default_rng(0)
    r = np.round(rng.uniform(0, 50, 300) / d) * d
    assert readability_g(r) == pytest.approx(d)


def test_unquantised_readings_have_no_readability():
    assert math.isnan(readability_g(np.random.default_rng(1).uniform(0, 50, 300)))


def _steps(thrust):
    return pd.DataFrame({"n_open": 1, "duty_pct": np.linspace(10, 90, len(thrust)),
                         "thrust_gf": thrust})


def test_scale_rel_combines_balance_linearity_and_stated_terms():
    steps = _steps([5.0, 10.0, 20.0, 30.0, 40.0])
    unc = table_uncertainty(steps, np.arange(0, 50, 0.01), extra_rel=0.01)
    bal = 0.02 / math.sqrt(3) / 20.0  # +/-2 d uniform over the median thrust
    assert unc.scale_rel == pytest.approx(math.hypot(bal, 0.01))
    assert "0.01 g measured" in unc.sources["scale_rel"] and "stated by the user" in unc.sources["scale_rel"]
    unc = table_uncertainty(steps, None, linearity_g=0.05)
    assert unc.scale_rel == pytest.approx(0.05 / math.sqrt(3) / 20.0)
    assert "NOT included: accumulator pressure" in unc.sources["scale_rel"]


def test_bench_fit_writes_the_uncertainty_into_the_table(tmp_path, capsys):
    table = ThrustTable.default()
    rows, t, w = [], 0.0, 0
    for k in (1, 2):
        for d in range(10, 91, 10):
            for phase, step, val in (("zero", -1, 0.0), ("dwell", w, float(table.per_nozzle(d, k)))):
                for i in range(5):
                    rows.append((t, w, phase, step, k if step >= 0 else 0, d if step >= 0 else 0,
                                 round(val + 0.01 * (i - 2), 2), 1))
                    t += 0.1
            w += 1
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    pd.DataFrame(rows, columns=["t_s", "window", "phase", "step", "n_open", "duty_pct",
                                "reading_gf", "stable"]).to_csv(run_dir / "raw.csv", index=False)
    assert main(["bench", "fit", str(run_dir), "--order", "3", "--scale-rel", "0.02",
                 "--out", str(tmp_path / "t.toml")]) == 0
    assert "table uncertainty:" in capsys.readouterr().out
    fitted = ThrustTable.load(tmp_path / "t.toml")
    assert fitted.states_uncertainty
    assert 0.02 < fitted.uncertainty.scale_rel < 0.021
    assert "readability 0.01 g" in fitted.uncertainty.sources["scale_rel"]
    cov = fitted.extra["fit"]["nozzles"]["1"]["covariance"]
    assert np.shape(cov) == (4, 4)


def test_an_exact_fit_writes_no_covariance_and_its_table_loads():
    """4 duty steps for a cubic: s^2 is undefined (NaN covariance); the table said so by
    failing to load ('covariance must be finite'). It now leaves the covariance out, says
    why, and loads."""
    from bench.fit import fit_steps

    t = ThrustTable.default()
    d = [20.0, 40.0, 60.0, 80.0]
    steps = pd.DataFrame({"n_open": 1, "duty_pct": d,
                          "thrust_gf": [float(t.per_nozzle(x, 1)) for x in d]})
    table = fit_steps(steps, 3).table()
    row = table.extra["fit"]["nozzles"]["1"]
    assert "covariance" not in row and "no residual" in row["covariance_note"]
    again = ThrustTable.from_dict(table.to_dict())
    assert not again.states_uncertainty
