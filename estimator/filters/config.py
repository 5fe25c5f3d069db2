"""The EKF's settings: the state layout, :class:`EkfConfig`, the named presets.

The 8-state filter's state ``z = (x, y, psi, u, v, r, m, Izz)`` (:data:`STATE_NAMES`,
:data:`STATE_UNITS`), the pose measurement's size, the parameter forms of the update, and
the settings every run of the filter reads (:class:`EkfConfig`: start, noise, underweighting,
step, known plant terms); :data:`PAPER` and :data:`PRESETS`; :func:`parse_state_values` for
``name=value`` lists on the command line. SI units throughout.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from estimator.plant.model import ARM_M
from estimator.plant.propagate import AugmentedPlant

STATE_NAMES = ("x", "y", "psi", "u", "v", "r", "mass", "izz")
STATE_UNITS = ("m", "m", "rad", "m/s", "m/s", "rad/s", "kg", "kg m^2")
NX = 8
NZ = 3
PARAM_FORMS = ("inverse", "direct")
INV_IDX = (6, 7)
"""Indices of mass and Izz in the 8-state filter (corrected as 1/m and 1/Izz)."""


def _known_plant(known, arm_m: float = ARM_M) -> AugmentedPlant:
    """The 8-state model: mass and Izz estimated, ``known = (ct, cr, kb, ax, ay)`` fixed."""
    ct, cr, kb, ax, ay = known
    return AugmentedPlant.of(("mass", "izz"), {"arm": arm_m, "ct": ct, "cr": cr, "kb": kb,
                                               "ax": ax, "ay": ay})


@dataclass(frozen=True)
class EkfConfig:
    """Filter settings (SI units).

    Attributes:
        x0: (8,) initial mean (x m, y m, psi rad, u m/s, v m/s, r rad/s, m kg, Izz kg m^2).
        sigma0: (8,) initial standard deviations, same units.
        q_psd: (8,) process-noise spectral density per state, units^2/s.
        sigma_meas: (3,) measurement standard deviations (m, m, rad).
        underweight: alpha of the underweighted update (0 = off).
        uw_trigger: underweighting is active while the largest eigenvalue of
            R^-1/2 H P H^T R^-1/2 exceeds this.
        max_step_s: longest RK4 step of the propagation, s.
        arm_m, ct, cr, kb, ax, ay: known plant terms (see :mod:`estimator.plant.model`).
        param_form: ``"inverse"`` (default): the measurement update corrects 1/m and 1/Izz
            (:func:`inverse_correction`); ``"direct"``: it corrects m and Izz (the paper's
            filter).
    """

    x0: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 5e-3)
    sigma0: tuple[float, ...] = (0.1, 0.1, math.radians(5.0), 0.1, 0.1, math.radians(2.0),
                                 1.0, 2e-3)
    q_psd: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1e-4, 0.0)
    sigma_meas: tuple[float, float, float] = (0.01, 0.01, math.radians(1.0))
    underweight: float = 0.0
    uw_trigger: float = 1.0
    max_step_s: float = 0.01
    arm_m: float = ARM_M
    ct: float = 0.0
    cr: float = 0.0
    kb: float = 0.0
    ax: float = 0.0
    ay: float = 0.0
    param_form: str = "inverse"

    def __post_init__(self):
        for name, n in (("x0", NX), ("sigma0", NX), ("q_psd", NX), ("sigma_meas", NZ)):
            v = getattr(self, name)
            if len(v) != n:
                raise ValueError(f"{name} needs {n} values, got {len(v)}")
        if any(s <= 0 for s in self.sigma_meas):
            raise ValueError("measurement sigmas must be positive")
        if any(q < 0 for q in self.q_psd) or any(s < 0 for s in self.sigma0):
            raise ValueError("process noise and initial sigmas must be non-negative")
        if self.underweight < 0:
            raise ValueError("underweighting alpha must be >= 0")
        if self.max_step_s <= 0:
            raise ValueError("max_step_s must be positive")
        if self.param_form not in PARAM_FORMS:
            raise ValueError(f"param_form must be one of {', '.join(PARAM_FORMS)}")
        object.__setattr__(self, "_inv", INV_IDX if self.param_form == "inverse" else ())
        object.__setattr__(self, "_q_nz", tuple((i, float(q)) for i, q in enumerate(self.q_psd)
                                               if q))
        object.__setattr__(self, "_plant", _known_plant(self.known, self.arm_m))

    @property
    def known_params(self) -> dict[str, float]:
        """The known plant terms by parameter name (``arm``, ``ct``, ``cr``, ``kb``, ``ax``,
        ``ay``), as :func:`estimator.batch.least_squares.batch_ls` and
        :class:`estimator.plant.propagate.AugmentedPlant` take them."""
        return {"arm": self.arm_m, "ct": self.ct, "cr": self.cr, "kb": self.kb, "ax": self.ax,
                "ay": self.ay}

    @property
    def plant(self) -> AugmentedPlant:
        """The filter's model: mass and Izz estimated, the known terms fixed."""
        return self._plant

    @property
    def P0(self) -> np.ndarray:
        return np.diag(np.square(self.sigma0))

    @property
    def R(self) -> np.ndarray:
        return np.diag(np.square(self.sigma_meas))

    @property
    def known(self) -> tuple[float, ...]:
        """(ct, cr, kb, ax, ay)."""
        return (self.ct, self.cr, self.kb, self.ax, self.ay)

    def with_(self, **kw) -> EkfConfig:
        return replace(self, **kw)


PAPER = EkfConfig()
"""The paper's EKF setting: 1e-4 kg^2/Hz on mass, its initial mean/std and 1 cm / 1 deg."""

PRESETS = {"paper": PAPER,
           "no-process-noise": PAPER.with_(q_psd=(0.0,) * NX)}


def parse_state_values(text: str, what: str = "value") -> dict[int, float]:
    """Parse ``name=value,...`` (names from STATE_NAMES, ``m`` for mass) into {index: value}."""
    alias = {"m": "mass", "i": "izz", "yaw": "psi"}
    out: dict[int, float] = {}
    for part in filter(None, (p.strip() for p in text.split(","))):
        if "=" not in part:
            raise ValueError(f"expected NAME={what}, got {part!r}")
        k, v = (s.strip() for s in part.split("=", 1))
        k = alias.get(k.lower(), k.lower())
        if k not in STATE_NAMES:
            raise ValueError(f"unknown state {k!r}; choose from {', '.join(STATE_NAMES)}")
        try:
            val = float(v)
        except ValueError:
            raise ValueError(f"{k}: not a number: {v!r}") from None
        if not math.isfinite(val):
            raise ValueError(f"{k}: must be finite")
        out[STATE_NAMES.index(k)] = val
    return out
