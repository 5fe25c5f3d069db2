"""Monte Carlo of batch least squares on a structure (``tpods estimate
montecarlo --structure F``).

The module Monte Carlo (:mod:`estimator.montecarlo`) runs the vectorised 8-state EKF of one
module. A structure's unknowns are mass, Izz about the centre of mass and the centre of mass
``(cx, cy)`` in the tracked frame; this study fits them by batch least squares, one run
after the other:

- the truth of each run: mass and Izz drawn uniformly within +/- ``spread`` (relative) of
  the structure's start (:meth:`common.structure.Structure.initial_guess`: its [body]
  values, else the modules as point masses), cx and cy uniformly within +/- ``com_spread_m``
  of the start's centre of mass;
- the run: the shared input (every module's channels) through the structure's virtual
  thrusts (:meth:`common.structure.Structure.virtual_thrust`, as ``tpods sim
  --structure``), simulated from rest at the origin with the pose noise and dropped frames
  asked for (:func:`estimator.plant.sim.simulate`), one noise seed per run;
- the fit: :func:`estimator.batch.least_squares.batch_ls` of mass, izz, cx, cy started at the
  structure's start (the truth unknown to it), with the true noise sigmas.

Statistics over the converged runs (``e`` = estimate - truth, ``sigma`` the fit's reported
1-sigma, ``P`` its covariance of the four parameters):

- per parameter: bias (mean ``e``; also in units of its standard error), sample std of
  ``e``, the mean reported sigma and the RMS one ``sqrt(mean sigma^2)``; ``std_over_sigma``
  = std / RMS sigma (the runs' sigmas differ with their truths, and the spread of errors
  drawn with different sigmas is their RMS, not their mean) and ``std_normalised`` = std of
  ``e / sigma`` (1 for a consistent estimate); the fractions of runs with ``|e| <= 2
  sigma`` and ``<= 3 sigma`` (0.954 and 0.997 for a consistent Gaussian estimate);
- NEES ``e^T P^-1 e`` per run (4 dof): its average over R runs with the two-sided 95 %
  bounds ``chi2.ppf([.025, .975], 4 R) / R``, and the fraction of runs inside the per-run
  95 % bounds ``chi2.ppf([.025, .975], 4)``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from tqdm import tqdm

from common import chi2  # scipy.stats.chi2 without its import cost
from common.errors import UserError
from estimator.batch.least_squares import batch_ls
from estimator.plant.inputs import make_input
from estimator.plant.model import PlantParams
from estimator.plant.sim import SimConfig, simulate

NAMES = ("mass", "izz", "cx", "cy")
UNITS = {"mass": "kg", "izz": "kgm2", "cx": "m", "cy": "m"}


@dataclass(frozen=True)
class StructureMcConfig:
    """Settings of a structure Monte Carlo (SI units; ``structure`` a
    :class:`common.structure.Structure`)."""

    structure: Any
    runs: int = 100
    spread: float = 0.2
    com_spread_m: float = 0.02
    duration_s: float = 60.0
    input: str = "phase-sine"
    seed: int = 0
    pose_rate_hz: float = 120.0
    cmd_rate_hz: float = 50.0
    drop: float = 0.0
    noise_pos_m: float = 0.01
    noise_yaw_rad: float = math.radians(1.0)
    amplitude_pct: float = 20.0
    omega_rad_s: float = 1.0
    clamp: bool = False

    def __post_init__(self):
        if self.runs < 2:
            raise UserError("--runs: at least 2 runs")
        if not 0 <= self.spread < 1:
            raise UserError(f"--spread must lie in [0, 1), got {self.spread:g}")
        if self.com_spread_m < 0:
            raise UserError(f"--com-spread must be >= 0 m, got {self.com_spread_m:g}")
        if not 0 <= self.drop < 1:
            raise UserError(f"--drop must lie in [0, 1), got {self.drop:g}")
        if not (self.noise_pos_m > 0 and self.noise_yaw_rad > 0):
            raise UserError("the pose noise sigmas must be positive (the fit weighs by them)")

    def to_dict(self) -> dict[str, Any]:
        s = self.structure
        return {"structure": s.name, "structure_file": str(s.source),
                **({"thrusters": s.n_channels} if s.kind == "vehicle" else {"modules": s.n_modules}),
                "runs": self.runs, "spread": self.spread, "com_spread_m": self.com_spread_m,
                "duration_s": self.duration_s, "input": self.input, "seed": self.seed,
                "pose_rate_hz": self.pose_rate_hz, "cmd_rate_hz": self.cmd_rate_hz,
                "drop": self.drop, "noise_pos_m": self.noise_pos_m,
                "noise_yaw_rad": self.noise_yaw_rad, "method": "ls", "estimated": list(NAMES),
                "start": self.structure.initial_guess()}


@dataclass
class StructureMcResult:
    """Per-run truth, estimate, reported sigma and NEES (rows: runs; columns: NAMES)."""

    config: StructureMcConfig
    truth: np.ndarray
    estimate: np.ndarray
    sigma: np.ndarray
    nees: np.ndarray
    converged: np.ndarray
    elapsed_s: float
    interrupted: bool = False
    messages: list[str] = field(default_factory=list)

    @property
    def done(self) -> int:
        """Runs simulated and fitted (all of them unless interrupted)."""
        return len(self.truth)

    def summary(self) -> dict[str, Any]:
        """JSON-ready statistics over the converged runs (see the module doc)."""
        ok = self.converged
        r = int(ok.sum())
        out: dict[str, Any] = {"runs": self.config.runs, "runs_done": self.done,
                               "runs_converged": r, "runs_failed": self.done - r,
                               "method": "ls", "structure": self.config.structure.name,
                               "estimated": list(NAMES), "interrupted": self.interrupted,
                               "elapsed_s": self.elapsed_s}
        if r < 2:
            out["note"] = "fewer than 2 converged runs: no statistics"
            return out
        e = self.estimate[ok] - self.truth[ok]
        s = self.sigma[ok]
        for j, n in enumerate(NAMES):
            u = UNITS[n]
            std = float(np.std(e[:, j], ddof=1))
            rms_sigma = float(np.sqrt(np.mean(s[:, j] ** 2)))
            out[f"bias_{n}_{u}"] = float(np.mean(e[:, j]))
            out[f"bias_{n}_sigmas"] = float(np.mean(e[:, j]) / (std / math.sqrt(r)))
            out[f"std_{n}_{u}"] = std
            out[f"mean_sigma_{n}_{u}"] = float(np.mean(s[:, j]))
            out[f"rms_sigma_{n}_{u}"] = rms_sigma
            out[f"std_over_sigma_{n}"] = std / rms_sigma
            out[f"std_normalised_{n}"] = float(np.std(e[:, j] / s[:, j], ddof=1))
            out[f"within_2sigma_{n}"] = float(np.mean(np.abs(e[:, j]) <= 2 * s[:, j]))
            out[f"within_3sigma_{n}"] = float(np.mean(np.abs(e[:, j]) <= 3 * s[:, j]))
        nees = self.nees[ok]
        p = len(NAMES)
        lo, hi = chi2.ppf([0.025, 0.975], p * r) / r
        out.update({"nees_mean": float(np.mean(nees)), "nees_dof": p,
                    "nees_mean_bounds_95": [float(lo), float(hi)],
                    "nees_mean_inside": bool(lo <= np.mean(nees) <= hi)})
        lo1, hi1 = chi2.ppf([0.025, 0.975], p)
        out["nees_run_bounds_95"] = [float(lo1), float(hi1)]
        out["nees_run_inside_frac"] = float(np.mean((nees >= lo1) & (nees <= hi1)))
        return out

    def runs_table(self) -> tuple[list[str], np.ndarray]:
        """Columns and rows of runs.csv: run, truth, estimate and sigma per parameter,
        NEES, converged (1/0)."""
        cols = ["run", *(f"truth_{n}" for n in NAMES), *(f"est_{n}" for n in NAMES),
                *(f"sigma_{n}" for n in NAMES), "nees", "converged"]
        data = np.column_stack([np.arange(self.done), self.truth, self.estimate, self.sigma,
                                self.nees, self.converged.astype(float)])
        return cols, data


def draw_truth(cfg: StructureMcConfig, rng: np.random.Generator) -> np.ndarray:
    """(runs, 4) true mass, izz, cx, cy around the structure's start (see the module doc)."""
    g = cfg.structure.initial_guess()
    n = cfg.runs
    m = g["mass"] * (1 + cfg.spread * rng.uniform(-1, 1, n))
    izz = g["izz"] * (1 + cfg.spread * rng.uniform(-1, 1, n))
    cx = g["cx"] + cfg.com_spread_m * rng.uniform(-1, 1, n)
    cy = g["cy"] + cfg.com_spread_m * rng.uniform(-1, 1, n)
    return np.column_stack([m, izz, cx, cy])


def run_structure_montecarlo(cfg: StructureMcConfig, progress: bool = False
                             ) -> StructureMcResult:
    """Simulate and fit ``cfg.runs`` structure runs (a tqdm bar on stderr with ``progress``).
    Ctrl-C ends the study early: the runs done so far are returned (``interrupted``)."""
    s = cfg.structure
    cmd_t, duty = make_input(cfg.input, cfg.duration_s, cfg.cmd_rate_hz, cfg.amplitude_pct,
                             cfg.omega_rad_s, n_channels=s.n_channels)
    thrust_t, thrust = s.input_profile(cmd_t, duty, clamp=cfg.clamp)  # a vehicle's valve timing too
    rng = np.random.default_rng(cfg.seed)
    truths = draw_truth(cfg, rng)
    seeds = rng.integers(0, 2**63 - 1, cfg.runs)
    start = s.initial_guess()
    est = np.full((cfg.runs, 4), np.nan)
    sig = np.full((cfg.runs, 4), np.nan)
    nees = np.full(cfg.runs, np.nan)
    conv = np.zeros(cfg.runs, bool)
    messages: list[str] = []
    t0 = time.perf_counter()
    done = 0
    interrupted = False
    bar = tqdm(total=cfg.runs, desc=f"structure {s.name}: batch LS", unit="run",
               disable=not progress, leave=False)
    try:
        for i in range(cfg.runs):
            m, izz, cx, cy = truths[i]
            sim = simulate(cmd_t, duty, PlantParams(m, izz, cx=cx, cy=cy), config=SimConfig(
                pose_rate_hz=cfg.pose_rate_hz, noise_pos_m=cfg.noise_pos_m,
                noise_yaw_rad=cfg.noise_yaw_rad, drop=cfg.drop, seed=int(seeds[i]),
                clamp=cfg.clamp), thrust_n=thrust, thrust_t=thrust_t)
            try:
                res = batch_ls(sim.pose_t, sim.pose, thrust_t, thrust, names=NAMES,
                               initial=dict(start), sigma_pos_m=cfg.noise_pos_m,
                               sigma_yaw_rad=cfg.noise_yaw_rad)
            except UserError as exc:
                messages.append(f"run {i}: {exc}")
            else:
                P = res.cov[6:, 6:]
                est[i] = res.z0[6:]
                sig[i] = res.sigma[6:]
                ok = bool(res.converged) and bool(np.all(np.isfinite(P)))
                if ok:
                    e = est[i] - truths[i]
                    nees[i] = float(e @ np.linalg.solve(P, e))
                else:
                    messages.append(f"run {i}: {res.message}")
                conv[i] = ok
            done = i + 1
            bar.update(1)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        bar.close()
    return StructureMcResult(cfg, truths[:done], est[:done], sig[:done], nees[:done],
                             conv[:done], time.perf_counter() - t0, interrupted, messages)


def summary_lines(res: StructureMcResult) -> list[str]:
    """The text report of ``tpods estimate montecarlo --structure``."""
    c = res.config
    s = res.summary()
    lines = [f"Monte Carlo of {c.structure.kind} {c.structure.name!r} ({c.structure.parts_text()}): "
             f"{res.done} runs x {c.duration_s:g} s, {c.input}, batch LS of mass, izz, cx, cy; "
             f"spread +/-{c.spread:g} (m, Izz), +/-{c.com_spread_m:g} m (cx, cy); "
             f"{res.elapsed_s:.1f} s"]
    if "note" in s:
        return [*lines, f"  {s['note']} ({s['runs_failed']} failed)"]
    lines.append(f"  {'':5} {'bias':>11} {'(s.e.)':>7} {'std':>10} {'mean sigma':>11} "
                 f"{'rms sigma':>10} {'std/rms':>8} {'std(e/s)':>8} {'<=2 sig':>8} {'<=3 sig':>8}")
    for n in NAMES:
        u = UNITS[n]
        lines.append(f"  {n:<5} {s[f'bias_{n}_{u}']:+11.3g} {s[f'bias_{n}_sigmas']:+7.2f} "
                     f"{s[f'std_{n}_{u}']:10.3g} {s[f'mean_sigma_{n}_{u}']:11.3g} "
                     f"{s[f'rms_sigma_{n}_{u}']:10.3g} {s[f'std_over_sigma_{n}']:8.3f} "
                     f"{s[f'std_normalised_{n}']:8.3f} {100 * s[f'within_2sigma_{n}']:7.1f}% "
                     f"{100 * s[f'within_3sigma_{n}']:7.1f}%")
    b = s["nees_mean_bounds_95"]
    lines.append(f"  NEES (4 dof) mean {s['nees_mean']:.3g}, 95 % bounds [{b[0]:.3g}, {b[1]:.3g}] "
                 f"({'inside' if s['nees_mean_inside'] else 'OUTSIDE'}); runs inside the per-run "
                 f"95 % bounds: {100 * s['nees_run_inside_frac']:.1f} %")
    lines.append("  units: mass kg, izz kg m^2, cx, cy m")
    if s["runs_failed"]:
        lines.append(f"  {s['runs_failed']} of {res.done} runs did not converge (left out)")
    return lines
