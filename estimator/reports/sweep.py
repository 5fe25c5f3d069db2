"""The estimator sweep: every method on many simulated runs unlike the paper's.

:func:`run_sweep` draws ``runs`` cases from a seed (:func:`draw_cases`), simulates each
one (:func:`estimator.plant.sim.simulate`), estimates it with each method through
:func:`estimator.estimate.estimate_run` exactly as ``tpods estimate batch`` does (``ls``:
batch least squares; ``ekf``: the filter from the command line's default start, paper
preset; ``ls-ekf``: the paper's LS start, ``reuse``), with the true pose noise given to the
estimator, and returns one row per run and method: the final errors in sigmas, the flags
(diverged, inconsistent, not converged, refused, plausibility warnings) and the time.

Cases (drawn independently per run):

- mass log-uniform in [0.3, 8] kg, Izz log-uniform in [5e-4, 5e-2] kg m^2;
- duration uniform in [20, 120] s; dropped frames uniform in [0, 30] %;
- pose noise log-uniform in [0.5, 5] mm and [0.2, 2] deg;
- input ``phase-sine`` or ``translate-rotate`` (equal odds); poses at 120 Hz, commands at
  50 Hz, the module at rest at the origin at t = 0.

The sweep's criteria (:meth:`SweepResult.summary`): per method, the final errors of
m and Izz within 4 sigma in at least 99 % of the runs, and no run beyond 6 sigma without
a flag. Pure: prints nothing (an optional ``progress`` callback), writes nothing;
:meth:`SweepResult.markdown` and :meth:`SweepResult.to_dict` are what ``tpods report
sweep`` writes.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from common.errors import UserError
from common.runfolder import Run
from common.thrust_table import ThrustTable
from estimator.estimate import FilterOptions, estimate_run
from estimator.plant.inputs import make_input
from estimator.plant.model import PlantParams
from estimator.plant.sim import SimConfig, simulate

SWEEP_METHODS = ("ls", "ekf", "ls-ekf")
INPUTS = ("phase-sine", "translate-rotate")
WITHIN = 4.0
"""A final error within this many sigma counts as covered."""
UNFLAGGED_LIMIT = 6.0
"""No run may end beyond this many sigma without a flag."""
NOTICE = "states no uncertainty"
"""A warning holding this is about the thrust table, the same on every run: not a flag."""
TARGET_FRACTION = 0.99
"""Share of runs whose final error must be within :data:`WITHIN` sigma."""

RANGES = {"mass_kg": (0.3, 8.0), "izz_kgm2": (5e-4, 5e-2), "duration_s": (20.0, 120.0),
          "drop": (0.0, 0.3), "noise_pos_m": (0.5e-3, 5e-3),
          "noise_yaw_deg": (0.2, 2.0)}


@dataclass(frozen=True)
class SweepCase:
    """One simulated run of the sweep (SI units; yaw noise in rad)."""

    index: int
    seed: int
    mass_kg: float
    izz_kgm2: float
    duration_s: float
    drop: float
    noise_pos_m: float
    noise_yaw_rad: float
    input: str
    pose_rate_hz: float = 120.0
    cmd_rate_hz: float = 50.0


def draw_cases(runs: int, seed: int = 0, *, duration_s: tuple[float, float] | None = None
               ) -> list[SweepCase]:
    """``runs`` cases from ``seed`` (see the module docstring); ``duration_s`` overrides
    the duration range (the quick test uses short runs)."""
    if runs < 1:
        raise UserError("the sweep needs at least one run")
    rng = np.random.default_rng(seed)
    lo_d, hi_d = duration_s or RANGES["duration_s"]

    def logu(lo, hi):
        return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))

    out = []
    for i in range(runs):
        m = logu(*RANGES["mass_kg"])
        izz = logu(*RANGES["izz_kgm2"])
        dur = float(rng.uniform(lo_d, hi_d))
        drop = float(rng.uniform(*RANGES["drop"]))
        npos = logu(*RANGES["noise_pos_m"])
        nyaw = math.radians(logu(*RANGES["noise_yaw_deg"]))
        inp = INPUTS[int(rng.integers(len(INPUTS)))]
        out.append(SweepCase(i, int(rng.integers(2**31 - 1)), m, izz, dur, drop, npos, nyaw, inp))
    return out


def simulate_case(case: SweepCase) -> Run:
    """The case as an in-memory run (commands, poses and the truth in ``meta``)."""
    cmd_t, duty = make_input(case.input, case.duration_s, case.cmd_rate_hz)
    res = simulate(cmd_t, duty, PlantParams(case.mass_kg, case.izz_kgm2),
                   config=SimConfig(pose_rate_hz=case.pose_rate_hz, noise_pos_m=case.noise_pos_m,
                                    noise_yaw_rad=case.noise_yaw_rad, drop=case.drop,
                                    seed=case.seed))
    meta = {"truth": {"mass_kg": case.mass_kg, "izz_kgm2": case.izz_kgm2, "arm_m": 0.05,
                      "initial_state": [0.0] * 6}}
    return Run(Path(f"sweep-case-{case.index}"), res.cmd_t, res.duty_pct, res.pose_t, res.pose,
               meta=meta)


def _sigmas(err: float, sigma: float) -> float:
    """|error| / sigma (inf without a usable sigma)."""
    if not (math.isfinite(err) and math.isfinite(sigma)) or sigma <= 0:
        return math.inf
    return abs(err) / sigma


def estimate_case(case: SweepCase, methods: Sequence[str] = SWEEP_METHODS,
                  filter_options: FilterOptions | None = None,
                  table: ThrustTable | None = None) -> list[dict[str, Any]]:
    """Simulate one case and estimate it with every method: one row per method."""
    run = simulate_case(case)
    table = table or ThrustTable.default()
    rows = []
    for method in methods:
        row: dict[str, Any] = {**asdict(case), "method": method}
        warnings: list[str] = []
        t0 = time.perf_counter()
        try:
            est = estimate_run(run, table, method=method, sigma_pos_m=case.noise_pos_m,
                               sigma_yaw_rad=case.noise_yaw_rad, filter_options=filter_options,
                               log=warnings.append)
        except UserError as exc:  # refused, naming why: a flag, no estimate
            row.update(refused=str(exc), elapsed_s=time.perf_counter() - t0, flagged=True,
                       mass_kg=math.nan, izz_kgm2=math.nan, mass_sigma_kg=math.nan,
                       izz_sigma_kgm2=math.nan, z_mass=math.inf, z_izz=math.inf,
                       z_max=math.inf, diverged=False, inconsistent=False, converged=False,
                       warnings=[])
            rows.append(row)
            continue
        d = est.to_dict()
        em = d["mass_kg"] - case.mass_kg
        ei = d["izz_kgm2"] - case.izz_kgm2
        zm = _sigmas(em, d["mass_sigma_kg"])
        zi = _sigmas(ei, d["izz_sigma_kgm2"])
        diverged = bool(d.get("diverged", False))
        inconsistent = bool(d.get("inconsistent", False))
        converged = bool(est.converged) and not diverged
        warnings = [w for w in warnings if w.startswith("tpods: warning")] or \
            list(d.get("warnings", []))
        # a table without a stated uncertainty (the default one) is a notice on every run,
        # not a flag on this run's estimate
        warnings = [w for w in warnings if NOTICE not in w]
        row.update(refused="", elapsed_s=time.perf_counter() - t0, mass_kg=d["mass_kg"],
                   izz_kgm2=d["izz_kgm2"], mass_sigma_kg=d["mass_sigma_kg"],
                   izz_sigma_kgm2=d["izz_sigma_kgm2"], z_mass=zm, z_izz=zi, z_max=max(zm, zi),
                   diverged=diverged, inconsistent=inconsistent, converged=converged,
                   warnings=warnings,
                   nis_tail_mean=d.get("nis_tail_mean"))
        row["flagged"] = bool(diverged or inconsistent or not converged or warnings)
        rows.append(row)
    return rows


def _job(args):
    case, methods, opts = args
    return estimate_case(case, methods, opts)


@dataclass
class SweepResult:
    """Rows of :func:`run_sweep` (one per run and method) and how they were made."""

    rows: list[dict[str, Any]]
    runs: int
    seed: int
    methods: tuple[str, ...]
    elapsed_s: float
    settings: dict[str, Any] = field(default_factory=dict)

    def summary(self) -> dict[str, dict[str, Any]]:
        """Per method: runs within 4 sigma, beyond 4 (flagged or not), beyond 6 without a
        flag, the worst unflagged error, the flags, and whether the sweep's criteria hold."""
        out = {}
        for m in self.methods:
            rs = [r for r in self.rows if r["method"] == m]
            n = len(rs)
            z = np.array([r["z_max"] for r in rs], float)
            flag = np.array([r["flagged"] for r in rs], bool)
            within = z <= WITHIN
            unflagged_z = z[~flag]
            worst_unflagged = float(unflagged_z.max()) if len(unflagged_z) else 0.0
            b6 = int(np.sum((z > UNFLAGGED_LIMIT) & ~flag))
            out[m] = {
                "runs": n, "within_4sigma": int(within.sum()),
                "within_4sigma_frac": float(within.mean()) if n else math.nan,
                "beyond_4sigma": int((~within).sum()),
                "beyond_4sigma_flagged": int((~within & flag).sum()),
                "beyond_4sigma_unflagged": int((~within & ~flag).sum()),
                "beyond_6sigma_unflagged": b6,
                "worst_unflagged_sigma": worst_unflagged,
                "worst_sigma": float(z[np.isfinite(z)].max()) if np.isfinite(z).any() else math.inf,
                "flagged": int(flag.sum()),
                "flagged_within_4sigma": int((within & flag).sum()),
                "diverged": int(sum(r["diverged"] for r in rs)),
                "inconsistent": int(sum(r["inconsistent"] for r in rs)),
                "not_converged": int(sum(not r["converged"] and not r["refused"] for r in rs)),
                "refused": int(sum(bool(r["refused"]) for r in rs)),
                "warned": int(sum(bool(r["warnings"]) for r in rs)),
                "median_sigma": float(np.median(z)) if n else math.nan,
                "mean_elapsed_s": float(np.mean([r["elapsed_s"] for r in rs])) if n else math.nan,
                "meets_target": bool(n and within.mean() >= TARGET_FRACTION and b6 == 0),
            }
        return out

    def markdown(self) -> str:
        """The summary as a markdown table (what docs/estimators.md quotes)."""
        s = self.summary()
        lines = [f"Sweep: {self.runs} runs (seed {self.seed}), {self.elapsed_s:.0f} s; "
                 f"target: within {WITHIN:g} sigma in >= {100 * TARGET_FRACTION:g} % of runs and "
                 f"none beyond {UNFLAGGED_LIMIT:g} sigma without a flag.", "",
                 "| method | within 4 sigma | beyond 4 sigma (flagged / not) | beyond 6 sigma unflagged "
                 "| worst unflagged | flagged (diverged / inconsistent / not converged / refused / "
                 "warned) | median | target |",
                 "|---|---|---|---|---|---|---|---|"]
        for m, r in s.items():
            lines.append(
                f"| {m} | {r['within_4sigma']} / {r['runs']} ({100 * r['within_4sigma_frac']:.1f} %) "
                f"| {r['beyond_4sigma']} ({r['beyond_4sigma_flagged']} / "
                f"{r['beyond_4sigma_unflagged']}) | {r['beyond_6sigma_unflagged']} "
                f"| {r['worst_unflagged_sigma']:.3g} | {r['flagged']} ({r['diverged']} / "
                f"{r['inconsistent']} / {r['not_converged']} / {r['refused']} / {r['warned']}) "
                f"| {r['median_sigma']:.2f} | {'met' if r['meets_target'] else 'NOT met'} |")
        return "\n".join(lines) + "\n"

    def to_dict(self) -> dict[str, Any]:
        def clean(v):
            if isinstance(v, float) and not math.isfinite(v):
                return None if math.isnan(v) else ("inf" if v > 0 else "-inf")
            return v

        return {"runs": self.runs, "seed": self.seed, "methods": list(self.methods),
                "elapsed_s": self.elapsed_s, "settings": self.settings,
                "summary": {m: {k: clean(v) for k, v in d.items()}
                            for m, d in self.summary().items()},
                "rows": [{k: clean(v) for k, v in r.items()} for r in self.rows]}


def run_sweep(runs: int = 300, seed: int = 0, methods: Sequence[str] = SWEEP_METHODS, *,
              duration_s: tuple[float, float] | None = None,
              filter_options: FilterOptions | None = None, workers: int = 1,
              progress: Callable[[int], None] | None = None) -> SweepResult:
    """Draw, simulate and estimate ``runs`` cases (see the module docstring).

    ``workers > 1`` spreads the cases over that many processes (each case is independent;
    on a machine whose cores are busy it gains little). ``progress(n)`` is called after each
    case with the number of cases done.
    """
    methods = tuple(methods)
    bad = [m for m in methods if m not in SWEEP_METHODS]
    if bad:
        raise UserError(f"unknown method(s) {', '.join(bad)}; choose from {', '.join(SWEEP_METHODS)}")
    if workers < 1:
        raise UserError("workers must be at least 1")
    cases = draw_cases(runs, seed, duration_s=duration_s)
    t0 = time.perf_counter()
    rows: list[dict[str, Any]] = []
    jobs = [(c, methods, filter_options) for c in cases]
    if workers == 1:
        for i, j in enumerate(jobs):
            rows.extend(_job(j))
            if progress is not None:
                progress(i + 1)
    else:
        import multiprocessing as mp  # lazy: only the parallel sweep needs a pool

        with mp.get_context("fork").Pool(workers) as pool:
            for i, rs in enumerate(pool.imap(_job, jobs)):
                rows.extend(rs)
                if progress is not None:
                    progress(i + 1)
    settings = {"ranges": dict(RANGES), "duration_s": list(duration_s or RANGES["duration_s"]),
                "filter_options": asdict(filter_options or FilterOptions()),
                "within_sigma": WITHIN, "unflagged_limit_sigma": UNFLAGGED_LIMIT,
                "target_fraction": TARGET_FRACTION, "workers": workers}
    return SweepResult(rows, runs, seed, methods, time.perf_counter() - t0, settings)
