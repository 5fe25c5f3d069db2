"""Reproduce the paper's Table 3: batch least squares for the orbit follower and the phase-shifted sine.

:func:`table3_cases` is the computation (simulate both cases, estimate from m = 1,
Izz = 0.005, CRLB at the truth, sensitivity summaries); :func:`write_table3` writes
report.md, table3.json, the simulated run folders and the figures.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from common.constants import PAPER_IZZ_KGM2, PAPER_MASS_KG
from common.thrust_table import ThrustTable
from common.thrust_uncertainty import thrust_sensitivity
from estimator.batch.consider import batch_consider
from estimator.batch.crlb import CRLBResult, crlb
from estimator.batch.least_squares import BatchResult, batch_ls
from estimator.plant.controller import run_orbit_follower
from estimator.plant.inputs import phase_sine
from estimator.plant.model import PlantParams, wrench
from estimator.plant.sim import SimConfig, SimResult, simulate, write_sim_run
from estimator.reports.plots.batch import plot_residuals, plot_sensitivities

TRUE_PLANT = PlantParams(PAPER_MASS_KG, PAPER_IZZ_KGM2)
INITIAL = {"mass": 1.0, "izz": 0.005}

PAPER = {
    "orbit": {"estimated": (2.317, 0.0061), "abs": (0.049, 0.0023), "rel": (2.16, 61.38)},
    "sine": {"estimated": (2.2661, 0.00378), "abs": (0.0018, 1.066e-6), "rel": (0.078, 0.0028)},
}
"""The paper's Table 3 (relative errors in percent)."""

CASE_TITLES = {"orbit": "Orbit follower", "sine": "Phase-shifted sine"}


@dataclass
class CaseResult:
    key: str
    sim: SimResult
    fit: BatchResult
    bound: CRLBResult
    summary: dict[str, float]


def _excitation_summary(sim: SimResult, bound: CRLBResult) -> dict[str, float]:
    """Numbers that explain observability: torque, yaw motion and output sensitivities."""
    seg = np.clip(np.searchsorted(sim.cmd_t, sim.pose_t, side="right") - 1, 0, len(sim.cmd_t) - 1)
    w = wrench(sim.thrust_n[seg], sim.params.arm_m)
    sy = bound.sens_x[:, :3, :] * np.array([sim.params.mass_kg, sim.params.izz_kgm2])
    return {
        "rms_force_n": float(np.sqrt(np.mean(w[:, 0] ** 2 + w[:, 1] ** 2))),
        "rms_torque_nm": float(np.sqrt(np.mean(w[:, 2] ** 2))),
        "max_abs_yaw_rate_rad_s": float(np.abs(sim.states[:, 5]).max()),
        "yaw_span_rad": float(np.ptp(sim.states[:, 2])),
        "max_excursion_m": float(np.abs(sim.states[:, :2] - sim.states[0, :2]).max()),
        # change of the outputs for a 100 % change of the parameter (rms over the run)
        "rms_dpos_dlnm_m": float(np.sqrt(np.mean(sy[:, 0, 0] ** 2 + sy[:, 1, 0] ** 2))),
        "rms_dyaw_dlnm_rad": float(np.sqrt(np.mean(sy[:, 2, 0] ** 2))),
        "rms_dpos_dlnizz_m": float(np.sqrt(np.mean(sy[:, 0, 1] ** 2 + sy[:, 1, 1] ** 2))),
        "rms_dyaw_dlnizz_rad": float(np.sqrt(np.mean(sy[:, 2, 1] ** 2))),
        "crlb_corr_mass_izz": float(bound.cov[0, 1] / (bound.sigma[0] * bound.sigma[1])),
    }


def simulate_case(key: str, duration_s: float, seed: int, table: ThrustTable) -> SimResult:
    """The simulated run of a Table 3 case (1 cm / 1 deg noise at 120 Hz)."""
    if key == "orbit":
        cmd_t, duty, _ = run_orbit_follower(duration_s, TRUE_PLANT, table)
    elif key == "sine":
        cmd_t, duty = phase_sine(duration_s, 50.0, 20.0, 1.0)
    else:
        raise ValueError(key)
    return simulate(cmd_t, duty, TRUE_PLANT, table, SimConfig(seed=seed))


def table3_cases(duration_s: float = 120.0, seed: int = 0, table: ThrustTable | None = None,
                 log: Callable[[str], None] | None = None) -> dict[str, CaseResult]:
    """Run both cases: simulate, estimate from the paper's initial guess, bound at the truth."""
    table = table or ThrustTable.default()
    out = {}
    for key in ("orbit", "sine"):
        if log:
            log(f"{CASE_TITLES[key]}: simulating {duration_s:g} s and estimating ...")
        sim = simulate_case(key, duration_s, seed, table)
        fit = batch_ls(sim.pose_t, sim.pose, sim.cmd_t, sim.thrust_n, initial=INITIAL)
        if table.states_uncertainty:  # the budget: the table's uncertainty as a consider term
            sens = thrust_sensitivity(table, sim.duty_pct)
            cons = batch_consider(fit, sim.cmd_t, sens, sigma_pos_m=0.01,
                                  sigma_yaw_rad=math.radians(1.0))
            fit.add_thrust_covariance(cons.cov_thrust, cons.names)
        bound = crlb(sim.pose_t, sim.cmd_t, sim.thrust_n, sim.params.kwargs(),
                     s0=sim.config.initial_state, keep_sensitivities=True)
        out[key] = CaseResult(key, sim, fit, bound, _excitation_summary(sim, bound))
    return out


def _fmt(v: float) -> str:
    return f"{v:.4g}" if abs(v) >= 1e-3 or v == 0 else f"{v:.3e}"


def table3_markdown(cases: dict[str, CaseResult]) -> str:
    """The Table 3 markdown (ours and the paper's numbers)."""
    hdr = ("| | Orbit follower: mass [kg] | Orbit follower: Izz [kg m^2] "
           "| Phase-shifted sine: mass [kg] | Phase-shifted sine: Izz [kg m^2] |")
    lines = [hdr, "|---|---|---|---|---|"]

    def row(label, f):
        cells = []
        for key in ("orbit", "sine"):
            cells += [f(key, 0), f(key, 1)]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")

    def est(key, j):
        fit = cases[key].fit
        return fit.mass_kg if j == 0 else fit.izz_kgm2

    def true(j):
        return TRUE_PLANT.mass_kg if j == 0 else TRUE_PLANT.izz_kgm2

    def sig(key, j):
        fit = cases[key].fit
        return fit.mass_sigma_kg if j == 0 else fit.izz_sigma_kgm2

    row("Initial", lambda k, j: _fmt(INITIAL["mass"] if j == 0 else INITIAL["izz"]))
    row("True", lambda k, j: _fmt(true(j)))
    row("Estimated", lambda k, j: _fmt(est(k, j)))
    row("Absolute error", lambda k, j: _fmt(abs(est(k, j) - true(j))))
    row("Relative error", lambda k, j: f"{abs(est(k, j) - true(j)) / true(j) * 100:.3g} %")
    def part(key, j, which):
        i = 6 + j
        fit = cases[key].fit
        return float((fit.sigma_noise if which == "noise" else fit.sigma_thrust)[i])

    row("Sigma: measurement noise", lambda k, j: _fmt(part(k, j, "noise")))
    row("Sigma: thrust table", lambda k, j: _fmt(part(k, j, "thrust")))
    row("Reported sigma (1 sigma, total)", lambda k, j: _fmt(sig(k, j)))
    row("CRLB sigma at the truth", lambda k, j: _fmt(cases[k].bound.sigma[j]))
    row("CRLB sigma / truth", lambda k, j: f"{cases[k].bound.sigma[j] / true(j) * 100:.3g} %")
    row("Error / reported sigma", lambda k, j: f"{(est(k, j) - true(j)) / sig(k, j):+.2f}")
    row("Paper: estimated", lambda k, j: _fmt(PAPER[k]["estimated"][j]))
    row("Paper: absolute error", lambda k, j: _fmt(PAPER[k]["abs"][j]))
    row("Paper: relative error", lambda k, j: f"{PAPER[k]['rel'][j]:.3g} %")
    return "\n".join(lines)


def _explanation(cases: dict[str, CaseResult]) -> str:
    o, s = cases["orbit"].summary, cases["sine"].summary
    ob, sb = cases["orbit"].bound, cases["sine"].bound
    ratio_izz = ob.sigma[1] / sb.sigma[1]
    return f"""## Why the orbit follower leaves Izz poorly observable

Izz enters the dynamics only through the yaw acceleration `rdot = Mz / Izz`, so the
measurements can only tell Izz through yaw motion driven by torque. Its output
sensitivity is `dpsi/dIzz = -(1/Izz) * integral of integral of Mz/Izz dt dt`:
without torque there is no sensitivity at all.

| | orbit follower | phase-shifted sine |
|---|---|---|
| rms thruster torque Mz [N m] | {o['rms_torque_nm']:.3g} | {s['rms_torque_nm']:.3g} |
| largest yaw rate [rad/s] | {o['max_abs_yaw_rate_rad_s']:.3g} | {s['max_abs_yaw_rate_rad_s']:.3g} |
| yaw span over the run [rad] | {o['yaw_span_rad']:.3g} | {s['yaw_span_rad']:.3g} |
| rms of Izz * dpsi/dIzz [rad] (yaw noise 0.0175 rad) | {o['rms_dyaw_dlnizz_rad']:.3g} | {s['rms_dyaw_dlnizz_rad']:.3g} |
| rms of m * d(x,y)/dm [m] (position noise 0.01 m) | {o['rms_dpos_dlnm_m']:.3g} | {s['rms_dpos_dlnm_m']:.3g} |
| largest excursion from the start [m] | {o['max_excursion_m']:.3g} | {s['max_excursion_m']:.3g} |
| CRLB correlation of m and Izz | {o['crlb_corr_mass_izz']:+.3f} | {s['crlb_corr_mass_izz']:+.3f} |

The orbit follower holds the yaw at zero and asks for a torque only to reject the
small yaw errors its own allocation makes, so the yaw barely moves and the yaw
sensitivity to Izz (a 100 % change of Izz moves the yaw by
{o['rms_dyaw_dlnizz_rad']:.2g} rad rms) is {o['rms_dyaw_dlnizz_rad'] / math.radians(1):.2g} times a
single frame's yaw noise, even summed over {ob.n_poses} frames. The Fisher information on Izz is therefore
tiny: the CRLB on Izz is {ob.sigma[1]:.3g} kg m^2 ({ob.sigma[1] / TRUE_PLANT.izz_kgm2 * 100:.3g} %
of the truth), {ratio_izz:.3g} times the bound of the phase-shifted sine. Izz values tens of percent
apart fit the data about equally well, consistent with the paper's 61 % error.
Mass stays observable in both cases because the translational sensitivity
(m d(x,y)/dm, {o['rms_dpos_dlnm_m']:.2g} m rms for the orbit follower) is many times the
position noise.

The phase-shifted sine fires the four valves out of phase, so the net torque
oscillates with a non-zero mean, the module spins ({s['yaw_span_rad']:.3g} rad over the run)
and the yaw sensitivity to Izz grows to {s['rms_dyaw_dlnizz_rad']:.3g} rad rms, {s['rms_dyaw_dlnizz_rad'] / math.radians(1):.3g}
times the yaw noise: Izz becomes as observable as the mass (Figure 6 right vs left).
Note that this input drifts {s['max_excursion_m']:.2g} m from its start in simulation: it
would leave a 2 m x 2 m table; `tpods design` finds sequences that stay on it.
"""


def write_table3(out_dir: str | Path, duration_s: float = 120.0, seed: int = 0,
                 table: ThrustTable | None = None, table_name: str = "built-in Table 2",
                 log: Callable[[str], None] | None = None) -> Path:
    """Compute both cases and write report.md, table3.json, run folders and figures."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    cases = table3_cases(duration_s, seed, table, log)
    figs = {}
    data: dict[str, Any] = {"duration_s": duration_s, "seed": seed, "thrust_table": table_name,
                            "true": {"mass_kg": TRUE_PLANT.mass_kg, "izz_kgm2": TRUE_PLANT.izz_kgm2},
                            "initial": INITIAL, "paper": PAPER, "cases": {}}
    for key, c in cases.items():
        write_sim_run(c.sim, out / "runs" / key, "orbit-follower" if key == "orbit" else "phase-sine",
                      table_name)
        figs[key] = {
            "residuals": plot_residuals(c.fit.t, c.fit.residuals, out / f"fig5_residuals_{key}.png",
                                        title=f"Fig. 5 ({CASE_TITLES[key]}): LS residuals").name,
            "sensitivities": plot_sensitivities(
                c.sim.pose_t, c.bound.sens_x, c.bound.names,
                [TRUE_PLANT.mass_kg, TRUE_PLANT.izz_kgm2], out / f"fig6_sensitivities_{key}.png",
                title=f"Fig. 6 ({CASE_TITLES[key]}): theta * dx/dtheta at the truth").name,
        }
        data["cases"][key] = {
            "estimate": c.fit.to_dict(),
            "crlb_mass_sigma_kg": c.bound.mass_sigma_kg,
            "crlb_izz_sigma_kgm2": c.bound.izz_sigma_kgm2,
            "summary": c.summary, "figures": figs[key],
        }
    md = ["# Table 3 reproduced: batch least squares (Algorithm 1)\n",
          f"Simulated with the foundation simulator: true m = {TRUE_PLANT.mass_kg} kg, "
          f"Izz = {TRUE_PLANT.izz_kgm2} kg m^2, arm 0.05 m, no friction; poses at 120 Hz with "
          f"1 cm / 1 deg Gaussian noise (seed {seed}); {duration_s:g} s; thrust table: {table_name}. "
          f"Initial guess m = 1 kg, Izz = 0.005 kg m^2, pose from the first frame, velocities zero; "
          f"diffuse prior; threshold 1e-8 on the largest scaled correction.\n",
          "- Orbit follower: PD controller (estimator/plant/controller.py) tracking x = 0.1 sin(2 pi t/60), "
          "y = 0.1 sin(2 pi t/60 + pi/2) - 0.1 m with the yaw held at zero, commands at 10 Hz, "
          "thrusts allocated by the inverse of the thrust table.",
          "- Phase-shifted sine: d_i = 50 + 20 sin(t + (i-1) pi/4) %, commands at 50 Hz.\n",
          table3_markdown(cases), "",
          f"Converged: orbit follower {cases['orbit'].fit.converged} "
          f"({cases['orbit'].fit.iterations} iterations), phase-shifted sine "
          f"{cases['sine'].fit.converged} ({cases['sine'].fit.iterations} iterations).",
          ("Uncertainty budget: the simulation blows the estimator's own thrust table, so the "
           "thrust table's part of the sigma is " + (
               "its stated uncertainty carried as a consider term (here the errors contain no "
               "thrust error: the estimates sit well inside the total sigma)."
               if (table or ThrustTable.default()).states_uncertainty else
               "0: the table states no uncertainty and is exact here, and the total is the "
               "noise sigma. On a real run the table's uncertainty adds to it "
               "(`tpods estimate batch` prints the budget; docs/estimators.md).")),
          "The CRLB is computed independently at the truth from the sensitivity equations "
          "(initial state marginalised by the Schur complement). Our estimator has only "
          "measurement noise to contend with, so its errors are a few sigma at most; "
          "the paper's orbit-follower mass error (2.16 %) is far above our bound and "
          "likely came from modelling differences in its simulation.\n",
          _explanation(cases), "",
          "## Figures\n",
          f"- Fig. 5 residuals: [orbit follower]({figs['orbit']['residuals']}), "
          f"[phase-shifted sine]({figs['sine']['residuals']})",
          f"- Fig. 6 sensitivities: [orbit follower]({figs['orbit']['sensitivities']}), "
          f"[phase-shifted sine]({figs['sine']['sensitivities']})",
          "- Simulated runs: `runs/orbit` and `runs/sine` (re-estimate with "
          "`tpods estimate batch runs/sine`).\n"]
    (out / "report.md").write_text("\n".join(md) + "\n")
    (out / "table3.json").write_text(json.dumps(data, indent=2, default=float) + "\n")
    return out / "report.md"


def relative_error(est: float, true: float) -> float:
    return abs(est - true) / true if true else math.nan
