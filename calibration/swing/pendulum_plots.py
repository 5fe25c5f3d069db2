"""The plot of a pendulum's test-mass check (matplotlib, Agg backend, PNG)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def plot_pendulum_check(res, path: str | Path) -> Path:
    """The swings' inertia against r^2 with the fitted line I0 + m_t r^2 and the line of the
    known test mass; the residuals below, in sigmas of each swing."""
    path = Path(path)
    r2 = np.asarray(res.radius_m) ** 2
    izz = np.asarray(res.izz_kgm2)
    s = np.asarray(res.izz_sigma_kgm2)
    x = np.linspace(0.0, float(r2.max()) * 1.05, 50)
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(8, 6.5), sharex=True,
                                   gridspec_kw={"height_ratios": [2, 1]})
    ax1.errorbar(r2, izz, yerr=s, fmt="o", ms=4, color="C0", label="swings")
    ax1.plot(x, res.i0_kgm2 + res.test_mass_kg * x, "-", color="C0",
             label=f"fit: I0 = {res.i0_kgm2:.6g} kg m$^2$, m_t = {res.test_mass_kg * 1e3:.4g} "
                   f"+- {res.test_mass_sigma_kg * 1e3:.2g} g")
    ax1.plot(x, res.i0_known_mass_kgm2 + res.known_test_mass_kg * x, "--", color="C3",
             label=f"known m_t = {res.known_test_mass_kg * 1e3:.4g} g "
                   f"(I0 = {res.i0_known_mass_kgm2:.6g} kg m$^2$)")
    ax1.set_ylabel("inertia (kg m$^2$)")
    ax1.set_title(f"Pendulum test-mass check: {res.verdict.upper()} "
                  f"({res.test_mass_difference_sigmas:+.1f} sigma, chi2/dof "
                  f"{res.chi2 / max(res.dof, 1):.3g})")
    ax1.legend(loc="upper left", fontsize=8)
    ax2.axhline(0.0, color="0.5", lw=0.8)
    ax2.plot(r2, np.asarray(res.residual_kgm2) / s, "o", ms=4, color="C0")
    ax2.set_ylabel("residual / sigma")
    ax2.set_xlabel("test-mass radius squared r$^2$ (m$^2$)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
