"""The figure of a structure: its outline, its modules with their thrusters,
the tracked frame, and the true and estimated centres of mass with their uncertainty
ellipses. PNG, Agg; a pure function of the values it is given.

The ellipse of a 2x2 covariance ``C`` at probability ``level`` (a 2-D Gaussian): the
semi-axes are ``k sqrt(lambda_i)`` with ``lambda_i`` the eigenvalues of ``C`` and
``k^2 = chi2_2^-1(level) = -2 ln(1 - level)`` (the chi-square quantile with two degrees of
freedom: 5.991 for 95 %), turned along the eigenvectors (:func:`ellipse_axes`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.patches import Ellipse, Polygon

from common.constants import ARM_M, MODULE_SIDE_M
from common.structure import module_wrench_1
from estimator.reports.plots.ekf import draw_error_band, save_time_panels

matplotlib.use("Agg")  # PNG files only, no window


def chi2_2dof_factor(level: float) -> float:
    """``k`` with ``P(chi^2_2 <= k^2) = level``: ``sqrt(-2 ln(1 - level))`` (2.448 for 95 %)."""
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must be in (0, 1), got {level!r}")
    return math.sqrt(-2.0 * math.log1p(-level))


def ellipse_axes(cov_m2, level: float = 0.95) -> tuple[float, float, float]:
    """(semi-major, semi-minor, angle of the major axis in degrees from x) of the
    ``level`` ellipse of a 2x2 covariance (same unit as the square root of ``cov_m2``)."""
    c = np.asarray(cov_m2, dtype=float)
    if c.shape != (2, 2) or not np.all(np.isfinite(c)):
        raise ValueError(f"need a finite 2x2 covariance, got {c!r}")
    lam, vec = np.linalg.eigh(0.5 * (c + c.T))  # ascending
    lam = np.maximum(lam, 0.0)
    k = chi2_2dof_factor(level)
    major = vec[:, 1]
    return (k * math.sqrt(lam[1]), k * math.sqrt(lam[0]),
            math.degrees(math.atan2(major[1], major[0])))


@dataclass(frozen=True)
class ComPoint:
    """One centre of mass to draw: ``label``, ``com_m`` (x, y in the tracked frame, m) and
    its 2x2 covariance ``cov_m2`` (None: a point without an ellipse, e.g. the truth)."""

    label: str
    com_m: tuple[float, float]
    cov_m2: Sequence[Sequence[float]] | None = None
    color: str = "C0"
    marker: str = "o"


def thruster_layout(arm_m: float = ARM_M, side_m: float = MODULE_SIDE_M
                    ) -> tuple[np.ndarray, np.ndarray]:
    """(4, 2) corner positions and (4, 2) unit force directions of a module's thrusters in
    its own frame: thruster i sits on the diagonal on which its force turns the module the
    way :func:`common.structure.module_wrench_1` says (moment ``r x F`` of sign Mz_i)."""
    w1 = module_wrench_1(arm_m)
    f = w1[:2].T  # (4, 2) unit directions
    sgn = np.sign(w1[2])
    r = sgn[:, None] * np.column_stack([f[:, 1], -f[:, 0]])  # r x f = sgn, |r| = 1
    return r * (side_m / 2.0) * math.sqrt(2.0), f


def _rot(deg: float) -> np.ndarray:
    a = math.radians(deg)
    return np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])


def _draw_module(ax, name: str, x: float, y: float, yaw_deg: float, side_m: float,
                 arm_m: float) -> None:
    rot = _rot(yaw_deg)
    h = side_m / 2.0
    sq = np.array([[-h, -h], [h, -h], [h, h], [-h, h]]) @ rot.T + (x, y)
    ax.add_patch(Polygon(sq, closed=True, fc="0.85", ec="k", lw=1.0, zorder=2))
    corners, dirs = thruster_layout(arm_m, side_m)
    for i, (c, d) in enumerate(zip(corners @ rot.T + (x, y), dirs @ rot.T, strict=True)):
        # the nozzle blows opposite to the force: draw the exhaust as a short arrow
        ax.annotate("", xy=c - 0.45 * side_m * d, xytext=c,
                    arrowprops=dict(arrowstyle="-|>", color="C3", lw=1.0), zorder=3)
        ax.plot(*c, "s", ms=3, color="C3", zorder=4)
        inner = c - 0.18 * side_m * (c - (x, y)) / np.linalg.norm(c - (x, y))
        ax.text(*inner, str(i + 1), fontsize=6, ha="center", va="center", zorder=4)
    ex = rot @ (0.35 * side_m, 0.0)
    ax.annotate("", xy=(x + ex[0], y + ex[1]), xytext=(x, y),
                arrowprops=dict(arrowstyle="->", color="0.3", lw=0.8), zorder=3)
    ax.text(x, y - 0.75 * side_m, f"{name}\nyaw {yaw_deg:g} deg", ha="center", va="top",
            fontsize=8, zorder=4)


def _ellipse(ax, center, cov, level: float, color: str, scale: float = 1.0, **kw) -> None:
    a, b, ang = ellipse_axes(cov, level)
    ax.add_patch(Ellipse(tuple(center), 2 * a * scale, 2 * b * scale, angle=ang, fc=color,
                         ec=color, alpha=0.25, lw=1.0, zorder=5, **kw))
    ax.add_patch(Ellipse(tuple(center), 2 * a * scale, 2 * b * scale, angle=ang, fc="none",
                         ec=color, lw=1.0, zorder=5))


def plot_structure(path: str | Path, modules: Sequence[tuple[str, float, float, float]],
                   points: Sequence[ComPoint], *, outlines: Sequence[np.ndarray] = (),
                   level: float = 0.95, arm_m: float = ARM_M, side_m: float = MODULE_SIDE_M,
                   title: str = "", inset_mm: float | None = None) -> Path:
    """The structure seen from above in its tracked frame (m), and a zoom on the centres of
    mass in millimetres from the first point (the truth, by convention).

    Args:
        path: the PNG to write.
        modules: (name, x_m, y_m, yaw_deg) of every module (its centre in the tracked frame).
        points: the centres of mass to draw, the first one the reference of the zoom; each
            with a covariance gets its ``level`` ellipse in both panels.
        outlines: (K, 2) polygons of the structure's other parts (the truss), m.
        level: probability of the ellipses (default 0.95).
        inset_mm: half-width of the zoom, mm (default: what holds every ellipse and point).
    """
    if not points:
        raise ValueError("need at least one centre of mass (the truth)")
    fig, (ax, zx) = plt.subplots(1, 2, figsize=(12, 5.6), gridspec_kw={"width_ratios": [1.5, 1]})
    for poly in outlines:
        ax.add_patch(Polygon(np.asarray(poly, float), closed=True, fc="#d8c3a5", ec="#8b6b4a",
                             lw=1.0, zorder=1))
    for name, x, y, yaw in modules:
        _draw_module(ax, name, x, y, yaw, side_m, arm_m)
    # the tracked frame: origin and axes
    ax_len = 0.08
    for d, lab in (((1, 0), "$x_s$"), ((0, 1), "$y_s$")):
        ax.annotate("", xy=(ax_len * d[0], ax_len * d[1]), xytext=(0, 0),
                    arrowprops=dict(arrowstyle="-|>", color="k", lw=1.4), zorder=6)
        ax.text(1.12 * ax_len * d[0], 1.12 * ax_len * d[1], lab, ha="center", va="center",
                fontsize=9, zorder=6)
    ax.plot(0, 0, "o", ms=4, color="k", zorder=6, label="tracked origin O")
    k = chi2_2dof_factor(level)
    ref = np.asarray(points[0].com_m, float)
    extent = 0.0
    for p in points:
        c = np.asarray(p.com_m, float)
        ax.plot(*c, p.marker, color=p.color, ms=7, mec="k", mew=0.6, zorder=7, label=p.label)
        d_mm = 1e3 * (c - ref)
        zx.plot(*d_mm, p.marker, color=p.color, ms=8, mec="k", mew=0.6, zorder=7, label=p.label)
        extent = max(extent, float(np.max(np.abs(d_mm))))
        if p.cov_m2 is not None:
            _ellipse(ax, c, p.cov_m2, level, p.color)
            _ellipse(zx, d_mm, np.asarray(p.cov_m2, float) * 1e6, level, p.color)
            a, _, _ = ellipse_axes(np.asarray(p.cov_m2, float) * 1e6, level)
            extent = max(extent, float(np.max(np.abs(d_mm))) + a)
    ax.set_aspect("equal")
    ax.autoscale_view()
    xs = [m[1] for m in modules] + [0.0] + [float(p.com_m[0]) for p in points]
    ys = [m[2] for m in modules] + [0.0] + [float(p.com_m[1]) for p in points]
    for poly in outlines:
        xs += list(np.asarray(poly)[:, 0])
        ys += list(np.asarray(poly)[:, 1])
    pad = 1.2 * side_m
    ax.set_xlim(min(xs) - pad, max(xs) + pad)
    ax.set_ylim(min(ys) - pad - 0.05, max(ys) + pad)
    ax.set_xlabel("$x_s$ [m] (tracked frame)")
    ax.set_ylabel("$y_s$ [m]")
    ax.grid(True, lw=0.3)
    ax.legend(fontsize=7, loc="upper left")
    ax.set_title("Structure, modules (red: thruster exhaust) and centres of mass", fontsize=10)
    half = inset_mm if inset_mm is not None else 1.15 * max(extent, 0.5)
    zx.set_xlim(-half, half)
    zx.set_ylim(-half, half)
    zx.set_aspect("equal")
    zx.axhline(0, color="0.6", lw=0.5)
    zx.axvline(0, color="0.6", lw=0.5)
    zx.grid(True, lw=0.3)
    zx.set_xlabel(f"x from the {points[0].label} [mm]")
    zx.set_ylabel(f"y from the {points[0].label} [mm]")
    zx.set_title(f"Zoom: centres of mass with their {100 * level:g} % ellipses\n"
                 f"(semi-axes {k:.3f} x sqrt(eigenvalues) of the 2x2 covariance)", fontsize=10)
    zx.legend(fontsize=7, loc="best")
    # mark the zoomed region in the overview
    box = np.array([[-half, -half], [half, -half], [half, half], [-half, half]]) * 1e-3 + ref
    ax.add_patch(Polygon(box, closed=True, fc="none", ec="0.3", lw=0.6, ls="--", zorder=8))
    if title:
        fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


_PARAM_LABELS = (("m", "kg", 1.0), ("Izz (centre of mass)", "kg m$^2$", 1.0),
                 ("cx", "mm", 1e3), ("cy", "mm", 1e3))


def plot_structure_errors(t, est, sigma, truth, path: str | Path, title: str = "") -> Path:
    """Errors of m, Izz, cx, cy (columns of ``est`` (N, 4) in kg, kg m^2, m, m) against time
    with their +/- 3 sigma bands (``sigma`` (N, 4)), one panel each; ``truth`` (4,)."""
    t = np.asarray(t, float)
    est = np.asarray(est, float)
    sigma = np.asarray(sigma, float)
    truth = np.asarray(truth, float)
    if est.shape != sigma.shape or est.ndim != 2 or est.shape[1] != 4 or truth.shape != (4,):
        raise ValueError("need est and sigma of shape (N, 4) and truth of shape (4,)")
    fig, axes = plt.subplots(4, 1, figsize=(8, 8.5), sharex=True)
    for j, ax in enumerate(axes):
        name, unit, f = _PARAM_LABELS[j]
        e = (est[:, j] - truth[j]) * f
        s3 = 3 * sigma[:, j] * f
        draw_error_band(ax, t, e, s3, f"{name}\nerror [{unit}]", ylabel_fontsize=9)
    return save_time_panels(fig, axes, path, title)
