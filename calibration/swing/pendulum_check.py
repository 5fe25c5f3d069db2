"""The test-mass check of an inertia pendulum: the pendulum's own calibration.

A known test mass m_t is placed at several radii r_i on the pendulum and each swing gives
an inertia I_i. A pendulum that measures correctly gives

    I_i = I0 + m_t r_i^2

with I0 the inertia of what hangs there without the test mass (plus the test mass's own
inertia about its centre, the same at every radius). The series is fitted by weighted least
squares for I0 and m_t; the fitted m_t against the known one, in sigmas, and the chi-square
of the fit are the verdict. A radius uncertainty u_r enters as an effective variance
(u_I^2 + (2 m_t r u_r)^2, iterated with the fitted m_t).

Swings given as periods use the small-angle formula of a pendulum with strings at radius R
(trifilar; a bifilar has R = D/2) of length L carrying the mass M plus the test mass:

    I = (M + m_t) g R^2 T^2 / (4 pi^2 L)

Each period's sigma is independent; the uncertainties of R, L, M and g are common to every
swing: they scale I0 and the fitted m_t together by one factor, whose relative sigma is added
to both (it cannot be seen in the fit's scatter, and it is what the test mass checks).

When chi^2/dof > 1 the fitted sigmas are scaled by sqrt(chi^2/dof) (the swings scatter more
than their sigmas say). Verdict: ``pass`` when the fitted m_t is within
:data:`PASS_SIGMAS` combined sigmas of the known one and the fit's p-value is at least
:data:`MIN_P_VALUE`; otherwise ``fail``, with the reasons. Pure functions on arrays.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from common import chi2 as chi2_dist
from common.constants import G_STANDARD_MPS2
from common.errors import UserError

PASS_SIGMAS = 2.0
"""The fitted test mass may differ from the known one by this many combined sigmas."""
MIN_P_VALUE = 0.01
"""Below this chi-square p-value the swings do not lie on I0 + m_t r^2 within their sigmas."""


@dataclass(frozen=True)
class PendulumGeometry:
    """Strings at ``radius_m`` from the axis (bifilar: half the spacing), ``length_m`` long,
    carrying ``mass_kg`` besides the test mass; standard uncertainties of each."""

    radius_m: float
    length_m: float
    mass_kg: float
    radius_sigma_m: float = 0.0
    length_sigma_m: float = 0.0
    mass_sigma_kg: float = 0.0
    g_mps2: float = G_STANDARD_MPS2
    g_sigma_mps2: float = 0.0

    def inertia_kgm2(self, period_s: np.ndarray, test_mass_kg: float) -> np.ndarray:
        """Small-angle inertia of each period with the test mass on board, kg m^2."""
        t = np.asarray(period_s, dtype=float)
        return ((self.mass_kg + test_mass_kg) * self.g_mps2 * self.radius_m**2 * t**2
                / (4 * math.pi**2 * self.length_m))

    def scale_rel_sigma(self, test_mass_kg: float, test_mass_sigma_kg: float = 0.0) -> float:
        """Relative sigma of the factor common to every swing (R, L, M + m_t, g)."""
        m = self.mass_kg + test_mass_kg
        return math.sqrt((2 * self.radius_sigma_m / self.radius_m) ** 2
                         + (self.length_sigma_m / self.length_m) ** 2
                         + (math.hypot(self.mass_sigma_kg, test_mass_sigma_kg) / m) ** 2
                         + (self.g_sigma_mps2 / self.g_mps2) ** 2)


def izz_from_periods(radius_m, period_s, period_sigma_s, geometry: PendulumGeometry,
                     test_mass_kg: float, test_mass_sigma_kg: float = 0.0
                     ) -> tuple[np.ndarray, np.ndarray, float]:
    """Each swing's inertia and its independent sigma (from the period), and the relative
    sigma of the factor common to all swings, from periods on ``geometry``."""
    t = np.asarray(period_s, dtype=float)
    st = np.asarray(period_sigma_s, dtype=float)
    if np.any(t <= 0) or np.any(st < 0):
        raise UserError("periods must be positive and their sigmas non-negative")
    izz = geometry.inertia_kgm2(t, test_mass_kg)
    return izz, 2 * izz * st / t, geometry.scale_rel_sigma(test_mass_kg, test_mass_sigma_kg)


@dataclass
class PendulumCheck:
    """The fit I = I0 + m_t r^2 of a test-mass series and its verdict (SI units)."""

    i0_kgm2: float
    i0_sigma_kgm2: float
    test_mass_kg: float
    test_mass_sigma_kg: float
    known_test_mass_kg: float
    known_test_mass_sigma_kg: float
    test_mass_difference_sigmas: float
    scale_factor: float
    scale_factor_sigma: float
    i0_known_mass_kgm2: float
    i0_known_mass_sigma_kgm2: float
    chi2: float
    dof: int
    p_value: float
    birge_ratio: float
    scale_rel_sigma: float
    verdict: str
    verdict_line: str
    reasons: list[str]
    radius_m: list[float] = field(default_factory=list)
    radius_sigma_m: list[float] = field(default_factory=list)
    izz_kgm2: list[float] = field(default_factory=list)
    izz_sigma_kgm2: list[float] = field(default_factory=list)
    residual_kgm2: list[float] = field(default_factory=list)
    covariance: list[list[float]] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)

    def summary(self) -> dict[str, Any]:
        """The few numbers a ground-truth report carries (calibration.composite)."""
        keys = ("verdict", "verdict_line", "i0_kgm2", "i0_sigma_kgm2", "test_mass_kg",
                "test_mass_sigma_kg", "known_test_mass_kg", "test_mass_difference_sigmas",
                "scale_factor", "scale_factor_sigma", "chi2", "dof", "p_value")
        return {k: getattr(self, k) for k in keys}


def _wls(r2: np.ndarray, izz: np.ndarray, var: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.column_stack([np.ones_like(r2), r2])
    w = 1.0 / var
    cov = np.linalg.inv(a.T @ (a * w[:, None]))
    return cov @ (a.T @ (w * izz)), cov


def check_series(radius_m, izz_kgm2, izz_sigma_kgm2, known_test_mass_kg: float,
                 known_test_mass_sigma_kg: float = 0.0, radius_sigma_m=None,
                 scale_rel_sigma: float = 0.0) -> PendulumCheck:
    """Fit I = I0 + m_t r^2 to a test-mass series and judge it.

    ``radius_m``, ``izz_kgm2``, ``izz_sigma_kgm2`` (and ``radius_sigma_m``): one value per
    swing (sigmas independent between swings); ``scale_rel_sigma``: relative sigma of a
    factor common to every swing's inertia (the pendulum's geometry, mass and g). At least
    three swings at two or more radii, positive sigmas."""
    r = np.asarray(radius_m, dtype=float)
    izz = np.asarray(izz_kgm2, dtype=float)
    s_i = np.asarray(izz_sigma_kgm2, dtype=float)
    s_r = np.zeros_like(r) if radius_sigma_m is None else np.asarray(radius_sigma_m, dtype=float)
    if not (r.shape == izz.shape == s_i.shape == s_r.shape) or r.ndim != 1:
        raise UserError("radius, inertia and sigma need one value per swing")
    if len(r) < 3:
        raise UserError(f"a test-mass series needs at least 3 swings, got {len(r)}")
    for name, v in (("radius", r), ("inertia", izz), ("inertia sigma", s_i), ("radius sigma", s_r)):
        if not np.all(np.isfinite(v)):
            raise UserError(f"a swing's {name} is not a finite number")
    if np.any(s_i <= 0):
        raise UserError("every swing needs a positive inertia sigma")
    if np.any(r < 0) or np.any(s_r < 0) or np.any(izz <= 0):
        raise UserError("radii, their sigmas and the inertias must not be negative")
    r2 = r**2
    if np.ptp(r2) <= 0:
        raise UserError("the test mass must be swung at two or more radii")
    if not known_test_mass_kg > 0 or known_test_mass_sigma_kg < 0:
        raise UserError("the known test mass must be positive and its sigma non-negative")
    m = known_test_mass_kg
    for _ in range(20):  # effective variance: the radius error moves I by 2 m r u_r
        var = s_i**2 + (2 * m * r * s_r) ** 2
        beta, cov = _wls(r2, izz, var)
        if abs(beta[1] - m) <= 1e-12 * max(abs(m), 1e-30):
            break
        m = float(beta[1])
    resid = izz - (beta[0] + beta[1] * r2)
    chi2 = float(np.sum(resid**2 / var))
    dof = len(r) - 2
    p = float(chi2_dist.sf(chi2, dof)) if dof > 0 else math.nan
    birge = math.sqrt(chi2 / dof) if dof > 0 and chi2 > dof else 1.0
    cov = cov * birge**2
    i0, mt = float(beta[0]), float(beta[1])
    s_i0 = math.sqrt(cov[0, 0] + (scale_rel_sigma * i0) ** 2)
    s_mt = math.sqrt(cov[1, 1] + (scale_rel_sigma * mt) ** 2)
    comb = math.hypot(s_mt, known_test_mass_sigma_kg)
    z = (mt - known_test_mass_kg) / comb
    k = mt / known_test_mass_kg
    s_k = abs(k) * math.hypot(s_mt / mt if mt else math.inf,
                              known_test_mass_sigma_kg / known_test_mass_kg)
    # I0 as a lab states it once the check passes: each swing minus the known m_t r^2
    w = 1.0 / (s_i**2 + (2 * known_test_mass_kg * r * s_r) ** 2 + (r2 * known_test_mass_sigma_kg) ** 2)
    i0k = float(np.sum(w * (izz - known_test_mass_kg * r2)) / np.sum(w))
    s_i0k = math.sqrt(1.0 / np.sum(w) * birge**2 + (scale_rel_sigma * i0k) ** 2)
    reasons = []
    if abs(z) > PASS_SIGMAS:
        reasons.append(f"the fitted test mass {mt * 1e3:.4g} +- {s_mt * 1e3:.2g} g is "
                       f"{z:+.1f} sigma from the known {known_test_mass_kg * 1e3:.4g} g "
                       f"({100 * (k - 1):+.1f} %): the pendulum's scale (R^2/L, its mass, g) "
                       "or the radii are off, or the inertia depends on the radius in a way "
                       "the model lacks (the centre of mass moving off the axis, a bending arm)")
    if dof > 0 and p < MIN_P_VALUE:
        reasons.append(f"the swings scatter about I0 + m_t r^2 more than their sigmas allow "
                       f"(chi2/dof = {chi2 / dof:.3g}, p = {p:.2g}): their sigmas are too small, "
                       "or the pendulum changed between swings")
    verdict = "pass" if not reasons else "fail"
    line = (f"pendulum check {verdict.upper()}: test mass {mt * 1e3:.4g} +- {s_mt * 1e3:.2g} g "
            f"against {known_test_mass_kg * 1e3:.4g} g known ({z:+.1f} sigma), "
            f"chi2/dof = {chi2 / dof if dof else math.nan:.3g} (p = {p:.2g}), "
            f"I0 = {i0:.6g} +- {s_i0:.2g} kg m^2")
    return PendulumCheck(
        i0_kgm2=i0, i0_sigma_kgm2=s_i0, test_mass_kg=mt, test_mass_sigma_kg=s_mt,
        known_test_mass_kg=known_test_mass_kg, known_test_mass_sigma_kg=known_test_mass_sigma_kg,
        test_mass_difference_sigmas=z, scale_factor=k, scale_factor_sigma=s_k,
        i0_known_mass_kgm2=i0k, i0_known_mass_sigma_kgm2=s_i0k, chi2=chi2, dof=dof, p_value=p,
        birge_ratio=birge, scale_rel_sigma=scale_rel_sigma, verdict=verdict, verdict_line=line,
        reasons=reasons, radius_m=r.tolist(), radius_sigma_m=s_r.tolist(), izz_kgm2=izz.tolist(),
        izz_sigma_kgm2=s_i.tolist(), residual_kgm2=resid.tolist(),
        covariance=[[float(x) for x in row] for row in cov])


def simulate_series(i0_kgm2: float, test_mass_kg: float, radius_m, izz_sigma_kgm2: float,
                    seed: int = 0) -> np.ndarray:
    """Inertias of a test-mass series with Gaussian noise of ``izz_sigma_kgm2`` (tests, docs)."""
    r = np.asarray(radius_m, dtype=float)
    rng = np.random.default_rng(seed)
    return i0_kgm2 + test_mass_kg * r**2 + rng.normal(0.0, izz_sigma_kgm2, r.shape)


SERIES_COLUMNS = ("radius_m", "izz_kgm2", "izz_sigma_kgm2", "period_s", "period_sigma_s",
                  "radius_sigma_m")


def read_series(path) -> dict[str, np.ndarray]:
    """A test-mass series CSV: one row per swing, ``radius_m`` and either ``izz_kgm2,
    izz_sigma_kgm2`` or ``period_s, period_sigma_s``; optional ``radius_sigma_m``; other
    columns ignored, ``#`` lines are comments. Returns the columns present as arrays; a
    missing column or a cell that is not a finite number is a UserError naming the line."""
    from pathlib import Path

    from common.csvlines import cell_number, read_csv_lines

    p = Path(path)
    numbered = read_csv_lines(p)
    if not numbered:
        raise UserError(f"{p}: empty (expected a header radius_m,izz_kgm2,izz_sigma_kgm2 "
                        "or radius_m,period_s,period_sigma_s)")
    lines = [(i, None) for i, _ in numbered]
    rows = [r for _, r in numbered]
    header = [h.strip() for h in rows[0]]
    if "radius_m" not in header:
        raise UserError(f"{p}: line {lines[0][0]}: no radius_m column (header {','.join(header)})")
    if {"izz_kgm2", "izz_sigma_kgm2"} <= set(header):
        wanted = ("radius_m", "izz_kgm2", "izz_sigma_kgm2")
    elif {"period_s", "period_sigma_s"} <= set(header):
        wanted = ("radius_m", "period_s", "period_sigma_s")
    else:
        raise UserError(f"{p}: needs columns izz_kgm2,izz_sigma_kgm2 or period_s,period_sigma_s "
                        f"beside radius_m (header {','.join(header)})")
    wanted += ("radius_sigma_m",) if "radius_sigma_m" in header else ()
    out: dict[str, list[float]] = {c: [] for c in wanted}
    for (lineno, _), row in zip(lines[1:], rows[1:], strict=True):
        if len(row) != len(header):
            raise UserError(f"{p}: line {lineno}: {len(row)} cells for {len(header)} columns")
        for c in wanted:
            cell = row[header.index(c)].strip()
            out[c].append(cell_number(cell, f"{p}: line {lineno}: column {c}", "a finite number"))
    return {c: np.array(v) for c, v in out.items()}


def load_check_summary(path, where: str = "pendulum_check") -> dict[str, Any]:
    """The summary (:meth:`PendulumCheck.summary`, plus ``file``) of a check's JSON written by
    ``tpods calibrate pendulum-check --json`` or ``--out``; a UserError naming ``where``
    when the file is missing or is not a check."""
    import json
    from pathlib import Path

    p = Path(path)
    try:
        doc = json.loads(p.read_text())
    except FileNotFoundError:
        raise UserError(f"{where}: {p}: file not found") from None
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise UserError(f"{where}: {p}: not a pendulum check's JSON ({exc.__class__.__name__})") from None
    keys = ("verdict", "verdict_line", "i0_kgm2", "i0_sigma_kgm2", "test_mass_kg",
            "test_mass_sigma_kg", "known_test_mass_kg", "test_mass_difference_sigmas",
            "scale_factor", "scale_factor_sigma", "chi2", "dof", "p_value")
    if not isinstance(doc, dict) or doc.get("verdict") not in ("pass", "fail") \
            or any(k not in doc for k in keys):
        raise UserError(f"{where}: {p}: not a pendulum check's JSON (tpods calibrate pendulum-check --json)")
    return {"file": str(p), **{k: doc[k] for k in keys}}
