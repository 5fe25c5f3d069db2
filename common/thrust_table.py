"""Thrust tables: per-nozzle thrust as a polynomial in PWM duty, one per nozzle count.

Thrust of one nozzle falls as more nozzles fire at once (shared air supply), so a
table holds one polynomial for each number ``k`` of simultaneously open valves.
The thrust of channel ``i`` is ``poly_k(D_i)`` with ``k`` the number of channels
with ``D > 0``; ``D == 0`` means closed and gives exactly 0 N.

The TOML format (see docs/run-format.md) is::

    unit = "gf"                 # or "N"
    duty_range = [10.0, 90.0]   # valid duty, percent
    pressure_psi = 60.0
    [nozzles.1]
    coefficients = [a0, a1, a2, a3]   # ascending powers of D (percent)
"""

from __future__ import annotations

import difflib
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from common.constants import GF_TO_N  # noqa: F401  (re-exported: tests and callers use it here)
from common.errors import UserError
from common.plausible import check_duty_range
from common.thrust_uncertainty import ThrustCalibration, ThrustUncertainty, coefficient_covariance
from common.tomlfile import read_toml

_UNIT_TO_N = {"gf": GF_TO_N, "N": 1.0}
NEGATIVE_TOLERANCE_FS = 0.01
"""A table may dip below zero by at most this fraction of a row's full scale (fit noise)."""

KNOWN_KEYS = ("unit", "duty_range", "pressure_psi", "nozzles", "uncertainty", "calibration")
"""The keys a thrust table is read by. Any other top-level key is kept in ``extra`` (fit
statistics, ``source``, notes) unless it looks like a misspelling of one of these."""


def _nearest(key: str, valid: tuple[str, ...], cutoff: float = 0.5) -> str:
    """The closest valid key, or ''."""
    near = difflib.get_close_matches(key, valid, n=1, cutoff=cutoff)
    return near[0] if near else ""


def _check_keys(data: Mapping[str, Any]) -> None:
    """UserError (without the source) for a top-level key that looks like a misspelled
    known key (``units``, ``duty-range``) and for any key in a [nozzles.k] but coefficients."""
    for key in data:
        near = "" if key in KNOWN_KEYS else _nearest(key.lower().replace("-", "_"), KNOWN_KEYS, 0.75)
        if near:
            raise UserError(f"unknown key {key!r} (did you mean {near!r}?)")
    nozzles = data.get("nozzles")
    if isinstance(nozzles, Mapping):
        for k, v in nozzles.items():
            if isinstance(v, Mapping):
                for key in v:
                    if key != "coefficients":
                        hint = " (did you mean 'coefficients'?)" if _nearest(key, ("coefficients",)) else ""
                        raise UserError(f"[nozzles.{k}]: unknown key {key!r}{hint}; it holds only "
                                        "coefficients")


@dataclass(frozen=True)
class ThrustTable:
    """Per-nozzle thrust polynomials indexed by the number of open nozzles.

    Attributes:
        coefficients: ``{k: (a0, a1, ...)}`` ascending powers of duty in percent,
            giving thrust in ``unit``.
        unit: ``"gf"`` or ``"N"``.
        duty_range: ``(low, high)`` valid duty in percent for an open valve.
        pressure_psi: accumulator pressure the table was measured at (or None).
        extra: any other top-level keys from the file (fit statistics, source).
        uncertainty: the table's stated scale uncertainty (``[uncertainty]``), or None.
        calibration: factors calibrated in situ (``[calibration]``), or None: thrust of
            channel j is multiplied by its efficiency and by the nozzle count's scale.
    """

    coefficients: Mapping[int, tuple[float, ...]]
    unit: str = "gf"
    duty_range: tuple[float, float] = (10.0, 90.0)
    pressure_psi: float | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)
    uncertainty: ThrustUncertainty | None = None
    calibration: ThrustCalibration | None = None

    def __post_init__(self) -> None:
        if self.unit not in _UNIT_TO_N:
            raise UserError(f"thrust table unit must be 'gf' or 'N', not {self.unit!r}")
        lo, hi = self.duty_range
        check_duty_range(lo, hi, "thrust table duty_range", f"write duty_range = [{hi:g}, {lo:g}]")
        if not (0.0 <= lo < hi <= 100.0):
            raise UserError(f"thrust table duty_range must satisfy 0 <= low < high <= 100, got {self.duty_range}")
        if not self.coefficients:
            raise UserError("thrust table has no [nozzles.k] entries")
        for k, c in self.coefficients.items():
            if not isinstance(k, int) or k < 1:
                raise UserError(f"thrust table nozzle count must be a positive integer, got {k!r}")
            if len(c) < 1 or not np.all(np.isfinite(c)):
                raise UserError(f"thrust table [nozzles.{k}] coefficients must be finite numbers")
            coefficient_covariance(self.extra, k, len(c))  # a malformed covariance is refused
        self._check_counts_exist()

    def _check_counts_exist(self) -> None:
        """An [uncertainty.nozzles.k] for a nozzle count the table has no row for would be
        ignored (and its sigma with it): refused, naming the entry."""
        per = self.uncertainty.nozzle_scale_rel if self.uncertainty is not None else {}
        for k in sorted(set(per) - set(self.coefficients)):
            have = ", ".join(str(c) for c in sorted(self.coefficients))
            raise UserError(f"[uncertainty.nozzles.{k}]: the table has no [nozzles.{k}] row (its "
                            f"rows: {have} open nozzle(s)); the entry would be ignored and its "
                            "uncertainty with it: fix the nozzle count or remove the entry")

    # ------------------------------------------------------------------ I/O
    @classmethod
    def from_dict(cls, data: Mapping[str, Any], source: str = "thrust table") -> ThrustTable:
        """A table from parsed TOML; UserError naming ``source`` on any problem.

        Integers and floats are both numbers (``duty_range = [10, 90]`` is fine); a
        boolean is not. ``unit`` is required: thrust in N read as gf is 100x off.
        """
        try:
            _check_keys(data)
        except UserError as exc:
            raise UserError(f"{source}: {exc}") from None

        def num(x: Any) -> float:
            if isinstance(x, bool):
                raise TypeError(f"{x!r} is not a number")
            return float(x)

        try:
            nozzles = data["nozzles"]
            if not isinstance(nozzles, Mapping):
                raise TypeError("nozzles must be tables [nozzles.1], [nozzles.2], ...")
            coeffs = {int(k): tuple(num(a) for a in v["coefficients"]) for k, v in nozzles.items()}
            unit = str(data.get("unit", "gf"))
            lo, hi = (num(x) for x in data.get("duty_range", (10.0, 90.0)))
            p = data.get("pressure_psi")
            p = None if p is None else num(p)
        except (KeyError, TypeError, ValueError) as exc:
            raise UserError(f"{source}: malformed thrust table ({exc.__class__.__name__}: {exc})") from None
        known = {"nozzles", "unit", "duty_range", "pressure_psi", "uncertainty", "calibration"}
        extra = {k: v for k, v in data.items() if k not in known}
        try:
            unc = ThrustUncertainty.from_dict(data["uncertainty"]) if "uncertainty" in data else None
            cal = ThrustCalibration.from_dict(data["calibration"]) if "calibration" in data else None
            table = cls(coeffs, unit, (lo, hi), p, extra, unc, cal)
        except UserError as exc:
            raise UserError(f"{source}: {exc}") from None
        if "unit" not in data:
            raise UserError(f'{source}: no unit: add unit = "gf" (gram-force) or unit = "N"')
        table.check_positive(source)
        return table

    def check_positive(self, source: str = "thrust table") -> None:
        """UserError naming the nozzle count and duty where a polynomial is negative inside
        ``duty_range`` by more than :data:`NEGATIVE_TOLERANCE_FS` of that row's full scale
        (a nozzle cannot pull: such a table is mistyped or badly fitted). A smaller dip, as
        a cubic fitted to bench data can make near the low end of its range, is within the
        fit's own accuracy (``bench fit`` meets Table 2 to < 1 % of full scale) and reads
        as 0 N there."""
        lo, hi = self.duty_range
        d = np.linspace(lo, hi, 801)
        for k in sorted(self.coefficients):
            v = self.per_nozzle(d, k)
            full_scale = float(np.max(np.abs(v)))
            if np.any(v < -NEGATIVE_TOLERANCE_FS * full_scale):
                i = int(np.argmin(v))
                raise UserError(
                    f"{source}: [nozzles.{k}] gives negative thrust {v[i]:.4g} {self.unit} at "
                    f"duty {d[i]:.4g} % ({k} nozzle(s) open); thrust must be positive over "
                    f"duty_range {lo:g}-{hi:g} % (check the coefficients' order and signs, or "
                    "narrow duty_range)")

    @classmethod
    def load(cls, path: str | Path) -> ThrustTable:
        """Read a TOML thrust table; raise UserError with the file name on any problem
        (:func:`common.tomlfile.read_toml`: a UTF-8 byte order mark is skipped, CRLF line
        ends are TOML)."""
        return cls.from_dict(read_toml(path, "thrust table"), str(path))

    @classmethod
    def default(cls) -> ThrustTable:
        """The paper's Table 2 (60 psi), shipped with the package."""
        text = resources.files("common").joinpath("data/table2_60psi.toml").read_text()
        return cls.from_dict(tomllib.loads(text), "built-in Table 2")

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "unit": self.unit,
            "duty_range": [float(self.duty_range[0]), float(self.duty_range[1])],
        }
        if self.pressure_psi is not None:
            out["pressure_psi"] = float(self.pressure_psi)
        out.update(self.extra)
        if self.uncertainty is not None:
            out["uncertainty"] = self.uncertainty.to_dict()
        if self.calibration is not None:
            out["calibration"] = self.calibration.to_dict()
        out["nozzles"] = {str(k): {"coefficients": [float(a) for a in self.coefficients[k]]}
                          for k in sorted(self.coefficients)}
        return out

    # ------------------------------------------------------------ uncertainty
    @property
    def newtons_per_unit(self) -> float:
        """N per unit of the table (9.80665e-3 for gf)."""
        return _UNIT_TO_N[self.unit]

    def channel_factors(self, n_channels: int) -> np.ndarray:
        """(n_channels,) calibrated efficiency of each channel (ones without a calibration)."""
        return np.ones(n_channels) if self.calibration is None else self.calibration.factors(n_channels)

    def nozzle_factor(self, k: int) -> float:
        """Calibrated scale of every nozzle when ``k`` are open (1 without a calibration)."""
        return 1.0 if self.calibration is None else float(self.calibration.nozzle_scale.get(k, 1.0))

    @property
    def states_uncertainty(self) -> bool:
        """True when the table states any uncertainty (scale, coefficient covariance or
        calibration covariance); False for a bare table such as the paper's Table 2."""
        if self.uncertainty is not None and (self.uncertainty.scale_rel > 0 or
                                             any(v > 0 for v in self.uncertainty.nozzle_scale_rel.values())):
            return True
        if self.calibration is not None and self.calibration.parameters:
            return True
        return any(coefficient_covariance(self.extra, k, len(c)) is not None
                   for k, c in self.coefficients.items())

    def save(self, path: str | Path) -> None:
        Path(path).write_text(tomli_w.dumps(self.to_dict()))

    # ---------------------------------------------------------- evaluation
    @property
    def max_nozzles(self) -> int:
        return max(self.coefficients)

    def per_nozzle(self, duty_pct: np.ndarray | float, k: int) -> np.ndarray:
        """Thrust of one nozzle in the table's unit at ``duty_pct`` with ``k`` nozzles open.

        No range check: this is the raw polynomial (for plots and fits).
        """
        if k not in self.coefficients:
            raise UserError(f"thrust table has no entry for {k} open nozzle(s)")
        c = np.asarray(self.coefficients[k], dtype=float)
        return np.polynomial.polynomial.polyval(np.asarray(duty_pct, dtype=float), c)

    def thrust_n(self, duty_pct: np.ndarray, clamp: bool = False) -> np.ndarray:
        """Per-channel thrust in newtons for duty rows.

        Args:
            duty_pct: shape ``(..., n_channels)``, duty in percent; 0 = closed.
            clamp: if True, open duties outside ``duty_range`` are clamped into it;
                otherwise they raise UserError.

        Returns:
            Array of the same shape, newtons; closed channels give exactly 0.
            A negative polynomial value (a table built in code; a file with one is
            refused on loading, :meth:`check_positive`) is returned as 0 N: a nozzle
            cannot pull.
        """
        d = np.asarray(duty_pct, dtype=float)
        if d.ndim == 0:
            raise UserError("duty must be given per channel")
        if not np.all(np.isfinite(d)):
            raise UserError("duty contains NaN or infinity")
        if np.any(d < 0) or np.any(d > 100):
            raise UserError(f"duty must lie in 0..100 %, got {d[(d < 0) | (d > 100)].ravel()[0]:g}")
        is_open = d > 0
        lo, hi = self.duty_range
        bad = is_open & ((d < lo) | (d > hi))
        if np.any(bad):
            if not clamp:
                raise UserError(
                    f"duty {d[bad].ravel()[0]:g} % is outside the thrust table's valid range "
                    f"{lo:g}-{hi:g} % (use the clamp option to saturate)")
            d = np.where(is_open, np.clip(d, lo, hi), 0.0)
        k = is_open.sum(axis=-1)
        out = np.zeros_like(d)
        for kk in np.unique(k):
            if kk == 0:
                continue
            rows = k == kk
            out[rows] = np.where(is_open[rows], self.per_nozzle(d[rows], int(kk)) *
                                 self.nozzle_factor(int(kk)), 0.0)
        if self.calibration is not None:
            out = out * self.channel_factors(d.shape[-1])
        return np.maximum(out, 0.0) * _UNIT_TO_N[self.unit]


def load_thrust_table(path: str | Path | None) -> ThrustTable:
    """The table at ``path``, or the paper's Table 2 when ``path`` is None."""
    return ThrustTable.default() if path is None else ThrustTable.load(path)
