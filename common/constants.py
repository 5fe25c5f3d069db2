"""Named constants used across the toolkit, SI units (the paper's values where noted).

One place for each number: the paper's module, the thruster geometry, gravity and the
gram-force. Import them; do not type them again.
"""

from __future__ import annotations

G_STANDARD_MPS2 = 9.80665
"""Standard gravity, m/s^2 (CGPM 1901; what balances and Table 2 in gram-force assume)."""

GF_TO_N = 9.80665e-3
"""One gram-force in newtons."""

ARM_M = 0.05
"""Moment arm of each thruster about the module centre, m (paper: d = 0.05 m)."""

MODULE_SIDE_M = 0.10
"""Side of the paper's square module, m (L in Izz = m L^2 / 6)."""

PAPER_MASS_KG = 2.268
"""Mass of the paper's simulated module, kg."""

PAPER_IZZ_KGM2 = 3.78e-3
"""Izz of the paper's simulated module, kg m^2: m L^2 / 6 (written as the paper rounds it;
the product in floating point differs in the last bit)."""

EXPERIMENT_MASS_KG = 0.720
"""Mass of the module weighed in the paper's experiment, kg."""


DEFAULT_DUTY_LIMITS = "10,90"
"""``--duty-limits``' default for a module, percent LOW,HIGH (a vehicle's is its own range)."""
