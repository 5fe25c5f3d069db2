"""The use case ``estimator.estimate.estimate_run`` from Python: the same numbers as
``tpods estimate batch --json``, for every method and for ``--model auto``."""

import json
import math

import pytest

from common.errors import UserError
from common.runfolder import read_run
from common.runwriter import json_default
from common.thrust_table import ThrustTable
from estimator.estimate import Estimate, FilterOptions, bound_sequence, estimate_run, load_sequence
from estimator.plant.inputs import phase_sine
from estimator.plant.model import PlantParams
from estimator.plant.sim import SimConfig, simulate, write_sim_run
from tests.support.cli import run_in_process


@pytest.fixture(scope="module")
def run_dirs(tmp_path_factory):
    base = tmp_path_factory.mktemp("usecase")
    cmd_t, duty = phase_sine(20.0, 50.0)
    out = {}
    for name, params in (("ideal", PlantParams(3.1, 6.5e-3)),
                         ("friction", PlantParams(2.268, 3.78e-3, ct=0.2, cr=5e-4, kb=1e-3))):
        res = simulate(cmd_t, duty, params, config=SimConfig(seed=5, drop=0.02))
        out[name] = write_sim_run(res, base / name)
    return out


def _same_json(est: Estimate, cli_stdout: str) -> None:
    """The result's JSON object is the one the CLI printed (same keys, same numbers);
    only the wall-clock time of the batch fit may differ."""
    ours = json.loads(json.dumps(est.to_dict(), default=json_default))
    theirs = json.loads(cli_stdout)
    for d in (ours, theirs):
        d.pop("elapsed_s", None)
    assert list(ours) == list(theirs)
    assert json.dumps(ours, sort_keys=True) == json.dumps(theirs, sort_keys=True)


@pytest.mark.parametrize("method,model,extra", [
    ("ls", None, ()),
    ("ekf", None, ()),
    ("ls-ekf", None, ("--ls-window", "8")),
    ("ls", "auto", ()),
    ("ls-ekf", "friction", ("--ls-window", "8")),
])
def test_estimate_run_equals_the_cli_json(tpods_exe, run_dirs, method, model, extra):
    d = run_dirs["ideal" if model is None else "friction"]
    args = ["estimate", "batch", str(d), "--method", method, "--json", *extra]
    if model:
        args += ["--model", model]
    r = run_in_process(*args)
    assert r.returncode == 0, r.stderr
    lines = []
    opts = FilterOptions(ls_window_s=8.0) if extra else None
    est = estimate_run(read_run(d), ThrustTable.default(), method=method, model=model,
                       filter_options=opts, log=lines.append)
    assert est.method == method
    _same_json(est, r.stdout)
    if model == "auto":
        assert est.model == "friction" and est.selection.chosen == "friction"
        sel = [ln for ln in lines if "states no uncertainty" not in ln]  # issue 17's note
        assert sel[0].startswith("model selection on") and sel[1:] == est.selection.table_lines()
        assert "chosen: friction" in r.stderr
    # exactly one result is set, by method and model
    kinds = [est.batch is not None, est.filter is not None, est.ext is not None]
    assert kinds == [method == "ls", method != "ls" and model is None,
                     method != "ls" and model is not None]


def test_a_path_and_the_defaults_work_too(run_dirs):
    est = estimate_run(run_dirs["ideal"], window=(2.0, 15.0))
    assert est.converged and est.model == "ideal" and est.run.pose_t[0] >= 2.0
    assert est.to_dict()["n_poses"] == len(est.run.pose_t)
    assert abs(est.batch.mass_kg - 3.1) < 4 * est.batch.mass_sigma_kg
    assert est.crlb is not None and est.has_truth


@pytest.mark.parametrize("window", ["abc", "5:2", (5.0, 2.0), "100:200"])
def test_a_bad_window_raises_user_error(run_dirs, window):
    with pytest.raises(UserError, match="window"):
        estimate_run(read_run(run_dirs["ideal"]), method="ls", window=window)


@pytest.mark.parametrize("kw,match", [
    ({"max_iter": 0}, "max-iter"),
    ({"model": "auto", "select_alpha": 2.0}, "select-alpha"),
    ({"method": "ekf", "estimate": ("mass", "izz", "ct")}, "exactly mass and izz"),
    ({"method": "kalman"}, "method"),
])
def test_bad_options_raise_user_error_before_reading(kw, match, tmp_path):
    # the options are checked first: the (missing) run folder is never read
    with pytest.raises(UserError, match=match):
        estimate_run(tmp_path / "missing", **kw)


def test_a_filter_refuses_to_fix_mass(run_dirs):
    with pytest.raises(UserError, match="fix only"):
        estimate_run(run_dirs["ideal"], method="ekf", fixed={"mass": 2.0})


def test_bound_sequence_equals_the_cli_json(tpods_exe, run_dirs):
    d = run_dirs["friction"]
    r = run_in_process("estimate", "crlb", str(d), "--model", "friction", "--window", "1:18",
            "--json")
    assert r.returncode == 0, r.stderr
    b = bound_sequence(load_sequence(d, ThrustTable.default()), path=str(d), window="1:18",
                       model="friction")
    assert json.loads(json.dumps(b.to_dict(), default=json_default)) == json.loads(r.stdout)
    assert b.plant_source == "run truth" and math.isfinite(b.crlb.mass_sigma_kg)


def test_implausible_residuals_reach_the_log_as_warnings(tmp_path, run_dirs):
    """issue 16: poses in millimetres gave 'converged; mass = 0.0023 kg +/- 9e-09' and no
    word; the warning now goes to ``log`` (what ``estimate batch`` prints) and the JSON."""
    import shutil

    import pandas as pd

    d = tmp_path / "mm"
    shutil.copytree(run_dirs["ideal"], d)
    p = pd.read_csv(d / "poses.csv")
    p.assign(x=p.x * 1000, y=p.y * 1000).to_csv(d / "poses.csv", index=False)
    lines: list[str] = []
    est = estimate_run(d, log=lines.append)
    assert any(ln.startswith("tpods: warning: position residuals") and "millimetres" in ln
               for ln in lines)
    note = [ln for ln in lines if "states no uncertainty" in ln]  # issue 17: said once
    assert len(note) == 1
    assert est.to_dict()["warnings"] == [ln.removeprefix("tpods: warning: ") for ln in lines
                                         if ln not in note]
    quiet: list[str] = []
    assert "warnings" not in estimate_run(run_dirs["ideal"], log=quiet.append).to_dict()
    assert quiet == note


def test_all_valves_closed_is_not_converged(tmp_path, run_dirs):
    import shutil

    import pandas as pd

    d = tmp_path / "closed"
    shutil.copytree(run_dirs["ideal"], d)
    c = pd.read_csv(d / "commands.csv")
    c[[k for k in c.columns if k != "t"]] = 0
    c.to_csv(d / "commands.csv", index=False)
    est = estimate_run(d)
    assert not est.converged
    assert "mass, izz have no information" in est.batch.message
    assert est.to_dict()["converged"] is False
