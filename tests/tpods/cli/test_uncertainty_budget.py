"""The uncertainty budget on the command line (issue 17, items 1-2).

`estimate batch --json`: mass_sigma_kg / izz_sigma_kgm2 are the TOTAL; the noise and thrust
parts sit beside them and their root-sum-square is the total. A table that states no
uncertainty (the paper's Table 2) gives the noise sigma and one warning line saying so.
`estimate crlb` prints the noise bound and the total.
"""

from __future__ import annotations

import json
import math

import pytest

from common.thrust_table import ThrustTable
from tpods.cli import main


@pytest.fixture(scope="module")
def run_and_tables(tmp_path_factory):
    d = tmp_path_factory.mktemp("budget")
    assert main(["sim", "--duration", "20", "--pose-rate", "60", "--out", str(d / "run")]) == 0
    t = ThrustTable.default().to_dict()
    t["uncertainty"] = {"scale_rel": 0.01, "source": "balance calibration, 1 %"}
    ThrustTable.from_dict(t).save(d / "scale.toml")
    return d / "run", d / "scale.toml"


def test_json_sigma_is_total_and_the_budget_adds_up(run_and_tables, capsys):
    run, table = run_and_tables
    capsys.readouterr()
    assert main(["estimate", "batch", str(run), "--thrust-table", str(table), "--json"]) == 0
    cap = capsys.readouterr()
    out = json.loads(cap.out)
    assert "no uncertainty" not in cap.err
    for name, unit in (("mass", "kg"), ("izz", "kgm2")):
        n, t, tot = (out[f"{name}_sigma_noise_{unit}"], out[f"{name}_sigma_thrust_{unit}"],
                     out[f"{name}_sigma_{unit}"])
        assert tot == pytest.approx(math.hypot(n, t), rel=1e-9)
        assert t > n > 0  # a 1 % scale error dominates a 20 s run's noise
        # a common scale error of 1 % moves m and Izz by 1 %
        assert t == pytest.approx(0.01 * out[f"{name}_{unit}"], rel=0.02)
    assert out["thrust_uncertainty"] == {"included": True, "terms": ["scale"],
                                         "note": out["thrust_uncertainty"]["note"]}
    assert out["sigma"]["mass"] == out["mass_sigma_kg"]


def test_text_output_shows_the_budget(run_and_tables, capsys):
    run, table = run_and_tables
    capsys.readouterr()
    assert main(["estimate", "batch", str(run), "--thrust-table", str(table)]) == 0
    text = capsys.readouterr().out
    assert "(1 sigma, total)" in text
    header = next(line for line in text.splitlines() if "uncertainty (1 sigma)" in line)
    assert header.split()[-3:] == ["noise", "thrust", "total"]
    assert any(line.strip().startswith("mass (kg)") for line in text.splitlines())


def test_a_table_without_uncertainty_says_sigma_is_noise_only(run_and_tables, capsys):
    run, _ = run_and_tables
    capsys.readouterr()
    assert main(["estimate", "batch", str(run), "--json"]) == 0
    cap = capsys.readouterr()
    out = json.loads(cap.out)
    warn = [line for line in cap.err.splitlines() if "states no uncertainty" in line]
    assert len(warn) == 1 and warn[0].startswith("tpods: warning: ")
    assert out["mass_sigma_thrust_kg"] == 0.0
    assert out["mass_sigma_kg"] == out["mass_sigma_noise_kg"]
    assert out["thrust_uncertainty"]["included"] is False


def test_crlb_prints_noise_bound_and_total(run_and_tables, capsys):
    run, table = run_and_tables
    capsys.readouterr()
    assert main(["estimate", "crlb", str(run), "--thrust-table", str(table), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["mass_sigma_total_kg"] == pytest.approx(
        math.hypot(out["crlb_mass_sigma_kg"], out["mass_sigma_thrust_kg"]))
    assert out["izz_sigma_thrust_kgm2"] == pytest.approx(0.01 * out["izz_kgm2"], rel=0.02)
    assert main(["estimate", "crlb", str(run), "--thrust-table", str(table)]) == 0
    text = capsys.readouterr().out
    assert "sigma >=" in text and "with the thrust table's uncertainty" in text


@pytest.mark.parametrize("body, needle", [
    ('[uncertainty]\nscale_rel = -0.01\n', "scale_rel must be >= 0"),
    ('[uncertainty]\nscale_rell = 0.01\n', "did you mean 'scale_rel'"),
    ('[uncertainty]\nscale_rel = "1 %"\n', "must be a number"),
    ('[fit.nozzles.1]\ncovariance = [[1.0, 0.0], [0.0, 1.0]]\n', "must be 4 x 4"),
    ('[fit.nozzles.1]\ncovariance = [[1.0, 2.0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]]\n',
     "not symmetric"),
    ('[fit.nozzles.1]\ncovariance = [[-1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]]\n',
     "not positive semi-definite"),
    ('[calibration]\nefficiency = [1.0, 0.0, 1.0, 1.0]\n', "must be positive"),
    ('[calibration]\nefficiency = [1.0, 1.0, 1.0, 1.0]\nparameters = ["efficiency.7"]\n'
     'covariance = [[1e-4]]\n', "name no factor"),
])
def test_bad_uncertainty_sections_are_one_line_errors(run_and_tables, tmp_path, capsys, body, needle):
    run, _ = run_and_tables
    base = (tmp_path / "t.toml")
    base.write_text('unit = "gf"\nduty_range = [10.0, 90.0]\n' + body + "\n" + "".join(
        f"[nozzles.{k}]\ncoefficients = [-9.0692, 1.0439, -0.0128, 7.88e-5]\n" for k in range(1, 5)))
    capsys.readouterr()
    assert main(["estimate", "batch", str(run), "--thrust-table", str(base)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("tpods: error: ") and needle in err and len(err.strip().splitlines()) == 1, err


@pytest.mark.parametrize("method", ["ekf", "ls-ekf"])
def test_filters_report_the_total_and_agree_with_batch_ls(run_and_tables, capsys, method):
    """Issue 17 item 3: a filter's sigma carries the thrust part too; without process noise
    on the parameters its total agrees with batch LS on the same run within 10 %."""
    run, table = run_and_tables
    capsys.readouterr()
    assert main(["estimate", "batch", str(run), "--thrust-table", str(table), "--json"]) == 0
    ls = json.loads(capsys.readouterr().out)
    assert main(["estimate", "batch", str(run), "--thrust-table", str(table), "--json",
                 "--method", method, "--preset", "no-process-noise"]) == 0
    f = json.loads(capsys.readouterr().out)
    assert f["thrust_uncertainty"]["included"]
    for name, unit in (("mass", "kg"), ("izz", "kgm2")):
        assert f[f"{name}_sigma_{unit}"] == pytest.approx(
            math.hypot(f[f"{name}_sigma_noise_{unit}"], f[f"{name}_sigma_thrust_{unit}"]))
        assert f[f"{name}_sigma_{unit}"] == pytest.approx(ls[f"{name}_sigma_{unit}"], rel=0.10)
    assert main(["estimate", "batch", str(run), "--thrust-table", str(table),
                 "--method", method]) == 0
    assert any(line.split()[-3:] == ["noise", "thrust", "total"]
               for line in capsys.readouterr().out.splitlines())
