"""The option objects of the estimate use cases (issue 26): :class:`EstimateOptions` and
:class:`BoundOptions` give the same results as the keyword arguments they replace, only
store settings, and an unknown keyword is a TypeError naming it."""

import dataclasses
import json

import pytest

from common.errors import UserError
from common.runwriter import json_default
from common.thrust_table import ThrustTable
from estimator.estimate import (
    BoundOptions,
    EstimateOptions,
    bound_sequence,
    estimate_run,
    load_sequence,
)
from estimator.plant.inputs import phase_sine
from estimator.plant.model import PlantParams
from estimator.plant.sim import SimConfig, simulate, write_sim_run


@pytest.fixture(scope="module")
def short_run(tmp_path_factory):
    cmd_t, duty = phase_sine(8.0, 50.0)
    res = simulate(cmd_t, duty, PlantParams(3.1, 6.5e-3), config=SimConfig(seed=3))
    return write_sim_run(res, tmp_path_factory.mktemp("opts") / "run")


def _json(d: dict) -> dict:
    d = json.loads(json.dumps(d, default=json_default))
    d.pop("elapsed_s", None)
    return d


def test_options_object_equals_keywords(short_run):
    kw = {"window": (1.0, 7.5), "sigma_pos_m": 0.02, "max_iter": 30}
    by_kw = estimate_run(short_run, **kw).to_dict()
    by_opts = estimate_run(short_run, None, EstimateOptions(**kw)).to_dict()
    assert _json(by_opts) == _json(by_kw)
    # keywords override the options' fields
    mixed = estimate_run(short_run, options=EstimateOptions(window=(0.0, 3.0), max_iter=30),
                         window=(1.0, 7.5), sigma_pos_m=0.02).to_dict()
    assert _json(mixed) == _json(by_kw)


def test_bound_options_object_equals_keywords(short_run):
    seq = load_sequence(short_run, ThrustTable.default())
    by_kw = bound_sequence(seq, path="p", window="1:7", model="friction").to_dict()
    by_opts = bound_sequence(seq, BoundOptions(window="1:7", model="friction"), path="p")
    assert _json(by_opts.to_dict()) == _json(by_kw)


def test_unknown_keyword_is_a_type_error_naming_it(tmp_path):
    with pytest.raises(TypeError, match="estimate_run.*'sigma_pos'"):
        estimate_run(tmp_path / "missing", sigma_pos=0.01)
    with pytest.raises(TypeError, match="bound_sequence.*'mass'"):
        bound_sequence(None, mass=2.0)
    with pytest.raises(TypeError, match="EstimateOptions"):
        estimate_run(tmp_path / "missing", None, BoundOptions())


def test_options_only_store_settings_and_are_checked_when_used(tmp_path):
    opts = EstimateOptions(method="kalman", max_iter=0)  # no check on construction
    assert opts.method == "kalman"
    with pytest.raises(dataclasses.FrozenInstanceError):
        opts.method = "ls"  # type: ignore[misc]
    with pytest.raises(UserError, match="method must be one of"):
        estimate_run(tmp_path / "missing", options=opts)
    with pytest.raises(UserError, match="max-iter"):
        estimate_run(tmp_path / "missing", options=opts, method="ls")
    assert opts.method == "kalman"  # the overrides leave the options object alone
