"""Report pages that print estimates show the uncertainty budget (issue 17, item 5)."""

from __future__ import annotations

from common.thrust_table import ThrustTable
from estimator.reports.table3 import table3_cases, table3_markdown


def _row(md: str, label: str) -> list[str]:
    line = next(x for x in md.splitlines() if x.startswith(f"| {label} |"))
    return [c.strip() for c in line.strip("|").split("|")[1:]]


def test_table3_shows_noise_thrust_and_total():
    d = ThrustTable.default().to_dict()
    d["uncertainty"] = {"scale_rel": 0.01}
    cases = table3_cases(duration_s=20.0, seed=1, table=ThrustTable.from_dict(d))
    md = table3_markdown(cases)
    noise = [float(c) for c in _row(md, "Sigma: measurement noise")]
    thrust = [float(c) for c in _row(md, "Sigma: thrust table")]
    total = [float(c) for c in _row(md, "Reported sigma (1 sigma, total)")]
    for n, t, tot in zip(noise, thrust, total, strict=True):
        assert t > 0 and abs(tot - (n * n + t * t) ** 0.5) <= 1e-3 * tot
    # a 1 % common scale: 1 % of the estimate
    sine = cases["sine"].fit
    assert abs(sine.sigma_thrust[6] / sine.mass_kg - 0.01) < 2e-4
    bare = table3_markdown(table3_cases(duration_s=20.0, seed=1))
    assert all(float(c) == 0.0 for c in _row(bare, "Sigma: thrust table"))
