"""Thrust-table uncertainty and in-situ calibration factors (common/thrust_uncertainty.py)."""

from __future__ import annotations

import numpy as np
import pytest

from common.thrust_table import ThrustTable
from common.thrust_uncertainty import thrust_sensitivity


def _table(**sections) -> ThrustTable:
    d = ThrustTable.default().to_dict()
    d.update(sections)
    return ThrustTable.from_dict(d)


DUTY = np.array([[30.0, 0.0, 30.0, 0.0], [40.0, 40.0, 40.0, 40.0], [0.0, 50.0, 0.0, 0.0]])


def test_calibration_factors_multiply_the_thrust_and_survive_a_round_trip(tmp_path):
    base = ThrustTable.default()
    cal = _table(calibration={"efficiency": [1.0, 0.95, 1.0, 1.02], "nozzle_scale": {"4": 1.03},
                              "parameters": ["efficiency.2", "nozzle_scale.4"],
                              "covariance": [[1e-4, 0.0], [0.0, 4e-4]], "source": "test"})
    want = base.thrust_n(DUTY) * np.array([1.0, 0.95, 1.0, 1.02])
    want[1] *= 1.03
    np.testing.assert_allclose(cal.thrust_n(DUTY), want, rtol=1e-12)
    cal.save(tmp_path / "t.toml")
    again = ThrustTable.load(tmp_path / "t.toml")
    np.testing.assert_allclose(again.thrust_n(DUTY), want, rtol=1e-12)
    assert again.calibration.info["source"] == "test"
    assert again.states_uncertainty and not base.states_uncertainty


def test_sensitivity_columns_are_derivatives_of_the_thrust():
    cov = np.diag([0.01, 1e-4, 1e-7, 1e-11])
    t = _table(uncertainty={"scale_rel": 0.01, "nozzles": {"2": {"scale_rel": 0.02}}},
               fit={"nozzles": {str(k): {"covariance": cov.tolist()} for k in range(1, 5)}},
               calibration={"efficiency": [1.0, 0.9, 1.0, 1.0], "parameters": ["efficiency.2"],
                            "covariance": [[1e-4]]})
    s = thrust_sensitivity(t, DUTY)
    # only the rows used: 1, 2 and 4 open (never 3)
    assert "coef.3.0" not in s.names and "coef.2.0" in s.names and "scale.2" in s.names
    d = t.to_dict()
    for name in ("scale", "scale.2", "coef.2.1", "coef.1.3", "efficiency.2"):
        p = s.names.index(name)
        h = 1e-6
        if name == "scale":
            up = dict(d, uncertainty={}, calibration=dict(d["calibration"]))
            up["nozzles"] = {k: {"coefficients": [c * (1 + h) for c in v["coefficients"]]}
                             for k, v in d["nozzles"].items()}
        elif name == "scale.2":
            up = dict(d)
            up["nozzles"] = dict(d["nozzles"])
            up["nozzles"]["2"] = {"coefficients": [c * (1 + h) for c in d["nozzles"]["2"]["coefficients"]]}
        elif name.startswith("coef"):
            _, k, j = name.split(".")
            up = dict(d)
            up["nozzles"] = dict(d["nozzles"])
            c = list(d["nozzles"][k]["coefficients"])
            c[int(j)] += h
            up["nozzles"][k] = {"coefficients": c}
        else:
            up = dict(d, calibration=dict(d["calibration"], efficiency=[1.0, 0.9 + h, 1.0, 1.0]))
        fd = (ThrustTable.from_dict(up).thrust_n(DUTY) - s.thrust_n) / h
        np.testing.assert_allclose(s.jacobian[..., p], fd, rtol=1e-4, atol=1e-9, err_msg=name)
    # the covariance is block diagonal in the stated terms
    assert s.covariance[s.names.index("scale"), s.names.index("scale")] == pytest.approx(1e-4)
    assert s.covariance[s.names.index("efficiency.2"), s.names.index("efficiency.2")] == pytest.approx(1e-4)
