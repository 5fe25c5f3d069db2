"""D-optimal inputs for in-situ thrust calibration (``tpods design --for thrust-calibration``).

A calibration run must open the thrusters in different combinations and numbers: the
paper's phase-shifted sine keeps all four open and cannot tell a nozzle-count scale from
the efficiencies' common level (:mod:`estimator.batch.thrust_calibration.calibrate`). The family
here is the *gated* phase-shifted sine

    d_i(t) = mean + A sin(w t + phase_i),   closed (0 %) where d_i(t) < low,

with ``mean + A <= high`` (``low``, ``high``: the table's valid duty range), so every open
duty is inside the table bounds and the number of open valves changes along the run.
Criterion: ``log det`` of the information on the factors (``per``) with the initial state
marginalised and m, Izz known (:func:`factor_information`), at the nominal table; a
candidate is feasible when the module's centre stays inside the table (less a margin)
and every factor asked for is excited. Search: random candidates, then Nelder-Mead on the
best few (as :func:`estimator.batch.design.search`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from common.errors import UserError
from common.thrust_table import ThrustTable
from estimator.batch.crlb import marginal_information, safe_inverse
from estimator.batch.design import DesignSettings
from estimator.batch.thrust_calibration.calibrate import (
    MODEL_EXTRAS,
    N_CHANNELS,
    CalibrationFit,
    counts_used,
    factor_names,
    normal_equations,
)
from estimator.plant.inputs import phase_sine
from estimator.plant.sim import pose_times


@dataclass(frozen=True)
class GatedSine:
    """A gated phase-shifted sine (duty percent, rad/s, rad); closed below ``low_pct``."""

    amplitude_pct: float
    omega_rad_s: float
    phases_rad: tuple[float, float, float, float]
    mean_pct: float
    low_pct: float

    def commands(self, duration_s: float, cmd_rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
        """``(t (Nc,), duty (Nc, 4))`` held commands, a closing row at ``duration_s``."""
        return gated_sine(duration_s, cmd_rate_hz, self.amplitude_pct, self.omega_rad_s,
                          self.mean_pct, self.phases_rad, self.low_pct)

    def describe(self) -> str:
        ph = ", ".join(f"{p:.3f}" for p in self.phases_rad)
        return (f"gated sine A = {self.amplitude_pct:.2f} %, w = {self.omega_rad_s:.4f} rad/s, "
                f"mean = {self.mean_pct:.1f} %, closed below {self.low_pct:g} %, phases = ({ph}) rad")


def gated_sine(duration_s: float, cmd_rate_hz: float, amplitude_pct: float, omega_rad_s: float,
               mean_pct: float, phases_rad, low_pct: float) -> tuple[np.ndarray, np.ndarray]:
    """``d_i = mean + A sin(w t + phase_i)``, 0 (closed) where it falls below ``low_pct``."""
    t, duty = phase_sine(duration_s, cmd_rate_hz, amplitude_pct, omega_rad_s, mean_pct,
                         tuple(phases_rad))
    return t, np.where(duty < low_pct, 0.0, duty)


@dataclass
class CalibrationEvaluation:
    """Score of one calibration input (see the module doc)."""

    logdet: float
    names: tuple[str, ...]
    sigma: np.ndarray  # (P,) noise sigma of each factor (m, Izz known)
    excursion_m: tuple[float, float]
    feasible: bool
    reason: str
    counts_s: dict[int, float]
    label: str = ""
    spec: GatedSine | None = None
    cmd_t: np.ndarray | None = None
    duty_pct: np.ndarray | None = None
    max_yaw_rate_rad_s: float = 0.0

    @property
    def score(self) -> float:
        return self.logdet if self.feasible else -math.inf

    def to_dict(self) -> dict:
        return {"label": self.label, "logdet_info": self.logdet, "feasible": self.feasible,
                "reason": self.reason, "factors": list(self.names),
                "sigma_noise": dict(zip(self.names, map(float, self.sigma), strict=True)),
                "nozzle_counts_s": {str(k): v for k, v in sorted(self.counts_s.items())},
                "excursion_x_m": self.excursion_m[0], "excursion_y_m": self.excursion_m[1],
                "max_yaw_rate_rad_s": self.max_yaw_rate_rad_s,
                **({"amplitude_pct": self.spec.amplitude_pct, "omega_rad_s": self.spec.omega_rad_s,
                    "phases_rad": list(self.spec.phases_rad), "mean_pct": self.spec.mean_pct,
                    "low_pct": self.spec.low_pct} if self.spec else {})}


def factor_information(cmd_t, duty_pct, table: ThrustTable, settings: DesignSettings,
                       names, model: str = "ideal") -> tuple[np.ndarray, np.ndarray]:
    """``(information (P, P) on the factors, states (N, 6))`` of a run from rest at the
    origin, m and Izz known (``settings.plant``), initial state and ``model``'s extras
    marginalised."""
    t_pose = pose_times(cmd_t[0], cmd_t[-1], settings.pose_rate_hz)
    extras = MODEL_EXTRAS[model]
    p = settings.plant
    fixed = {"mass": p.mass_kg, "izz": p.izz_kgm2, "arm": p.arm_m}
    fixed.update({k: 0.0 for k in ("ct", "cr", "kb", "ax", "ay") if k not in extras})
    w = np.array([settings.sigma_pos_m**-2, settings.sigma_pos_m**-2, settings.sigma_yaw_rad**-2])
    fit = CalibrationFit(t_pose, np.zeros((len(t_pose), 3)), np.asarray(cmd_t, float),
               np.asarray(duty_pct, float), table, tuple(names), extras, fixed, w, False,
               0.01)
    f0 = np.ones(len(names))
    z = np.concatenate([np.zeros(6 + len(extras)), f0])
    _, _, cache = fit.evaluate(z)
    if cache is None:
        raise UserError("the candidate's trajectory is not finite")
    H, _ = fit.jacobian(z, cache)
    Lam, _ = normal_equations(H, w, np.zeros((len(t_pose), 3)))
    states = cache[3][cache[1].node_pos]
    return marginal_information(Lam, fit.ne), states


def evaluate_calibration(cmd_t, duty_pct, table: ThrustTable, settings: DesignSettings,
                         per: str = "both", model: str = "ideal", label: str = "",
                         spec: GatedSine | None = None) -> CalibrationEvaluation:
    """D-optimal criterion on the factors and the workspace check of a duty sequence."""
    cmd_t = np.asarray(cmd_t, float)
    duty_pct = np.asarray(duty_pct, float)
    counts = counts_used(duty_pct, cmd_t, float(cmd_t[-1]))
    try:
        names, _ = factor_names(per, duty_pct, cmd_t, float(cmd_t[-1]))
    except UserError as exc:
        return CalibrationEvaluation(-math.inf, (), np.zeros(0), (math.nan, math.nan), False,
                                     str(exc), counts, label, spec, cmd_t, duty_pct)
    M, states = factor_information(cmd_t, duty_pct, table, settings, names, model)
    sign, logdet = np.linalg.slogdet(M)
    cov = safe_inverse(M)
    sig = np.sqrt(np.maximum(np.diag(cov), 0.0))
    exc = np.abs(states[:, :2] - states[0, :2]).max(axis=0)
    half = np.asarray(settings.table_size_m, float) / 2 - settings.margin_m
    reason = ""
    if not (sign > 0 and np.all(np.isfinite(sig))):
        reason = "the factors are confounded on this input"
        logdet = -math.inf
    elif not np.all(exc <= half):
        reason = f"leaves the table (excursion {exc[0]:.2f}, {exc[1]:.2f} m)"
    yaw_rate = float(np.abs(states[:, 5]).max())
    if not reason and settings.max_yaw_rate_rad_s is not None and yaw_rate > settings.max_yaw_rate_rad_s:
        reason = f"yaw rate {yaw_rate:.2f} rad/s above the limit"
    return CalibrationEvaluation(float(logdet), names, sig, (float(exc[0]), float(exc[1])),
                                 not reason, reason, counts, label, spec, cmd_t, duty_pct,
                                 yaw_rate)


def _decode(x, lo: float, hi: float, w_range) -> GatedSine:
    """Unconstrained (7,) -> mean in [lo, hi), A in (0, hi - mean], w in w_range, phases."""
    s = 1 / (1 + np.exp(-np.asarray(x[:3], float)))
    mean = lo + (hi - lo) * 0.95 * s[0]
    a = (hi - mean) * (0.05 + 0.95 * s[1])
    lw0, lw1 = math.log(w_range[0]), math.log(w_range[1])
    w = math.exp(lw0 + (lw1 - lw0) * s[2])
    return GatedSine(float(a), float(w), tuple(float(np.mod(p, 2 * math.pi)) for p in x[3:7]),
                     float(mean), lo)


@dataclass
class CalibrationDesign:
    best: CalibrationEvaluation
    history: list[CalibrationEvaluation]

    @property
    def evaluated(self) -> int:
        return len(self.history)


def search_calibration(table: ThrustTable, settings: DesignSettings, *, per: str = "both",
                       model: str = "ideal", n_random: int = 32, n_refine: int = 1,
                       refine_evals: int = 30, omega_range: tuple[float, float] = (0.2, 4.0),
                       seed: int = 0, progress: Callable[[int], None] | None = None
                       ) -> CalibrationDesign:
    """Search the gated-sine family for the largest feasible log det on the factors."""
    from scipy.optimize import minimize

    if model not in MODEL_EXTRAS:
        raise UserError(f"--model must be one of {', '.join(MODEL_EXTRAS)} for a calibration design")
    lo, hi = table.duty_range
    rng = np.random.default_rng(seed)
    history: list[CalibrationEvaluation] = []

    def ev(x) -> CalibrationEvaluation:
        spec = _decode(x, lo, hi, omega_range)
        cmd_t, duty = spec.commands(settings.duration_s, settings.cmd_rate_hz)
        e = evaluate_calibration(cmd_t, duty, table, settings, per, model, spec.describe(), spec)
        history.append(e)
        if progress:
            progress(1)
        return e

    starts = []
    for _ in range(n_random):
        x = np.concatenate([rng.normal(0, 1.5, 3), rng.uniform(0, 2 * math.pi, N_CHANNELS)])
        starts.append((x, ev(x)))
    ranked = sorted((s for s in starts if s[1].feasible), key=lambda s: -s[1].score)
    for x0, _ in ranked[:n_refine]:
        with np.errstate(invalid="ignore"):
            minimize(lambda x: -ev(x).score, x0, method="Nelder-Mead",
                     options={"maxfev": refine_evals,
                              "initial_simplex": x0 + 0.3 * np.vstack([np.zeros(7), np.eye(7)])})
    feasible = [e for e in history if e.feasible]
    if not feasible:
        reasons = sorted({e.reason for e in history})
        raise UserError("no calibration input found that separates the factors and keeps the "
                        f"module on the table ({'; '.join(reasons[:3])}); shorten --duration, "
                        "enlarge --table-size or add candidates")
    best = max(feasible, key=lambda e: e.score)
    best.label = "best " + best.label
    return CalibrationDesign(best, history)


@dataclass
class CalibrationDesignReport:
    """The use case's answer: the search ``result``, the ``compared`` inputs' evaluations,
    ``doc`` (design.json) and ``lines`` (its text report)."""

    result: CalibrationDesign
    compared: list[CalibrationEvaluation]
    doc: dict
    lines: list[str]


def design_thrust_calibration(table: ThrustTable, settings: DesignSettings, out_folder, *,
                              per: str = "thruster", compare: tuple[str, ...] = (),
                              candidates: int = 200, refine: int = 3, refine_evals: int = 60,
                              omega_range: tuple[float, float] = (0.2, 2.0), seed: int = 0,
                              progress: Callable[[int], object] | None = None) -> CalibrationDesignReport:
    """The D-optimal gated sine for the factors ``per`` (m and Izz known: ``settings.plant``),
    compared with the phase-shifted sine, translate-rotate and the ``compare`` inputs;
    written as commands.csv (t, d1..d4: s, %) and design.json into ``out_folder`` (a checked
    :class:`common.outputs.ResultFolder`). ``progress(n)`` is called as evaluations finish."""
    from estimator.plant.inputs import make_input

    s = settings
    compared = []
    for spec in ["phase-sine", "translate-rotate", *compare]:
        cmd_t, duty = make_input(spec, s.duration_s, s.cmd_rate_hz)
        try:
            compared.append(evaluate_calibration(cmd_t, duty, table, s, per, label=spec))
        except UserError as exc:
            raise UserError(f"{spec}: {exc}") from None
    res = search_calibration(table, s, per=per, n_random=candidates, n_refine=refine,
                             refine_evals=refine_evals, omega_range=tuple(omega_range), seed=seed,
                             progress=progress)
    best = res.best
    doc = {"for": "thrust-calibration", "per": per, "best": best.to_dict(),
           "compared": [e.to_dict() for e in compared], "evaluated": res.evaluated,
           "settings": {"duration_s": s.duration_s, "cmd_rate_hz": s.cmd_rate_hz,
                        "pose_rate_hz": s.pose_rate_hz, "table_size_m": list(s.table_size_m),
                        "margin_m": s.margin_m, "max_yaw_rate_rad_s": s.max_yaw_rate_rad_s,
                        "mass_kg": s.plant.mass_kg, "izz_kgm2": s.plant.izz_kgm2},
           "commands_csv": str(out_folder.path / "commands.csv")}
    with out_folder.writing() as d:
        np.savetxt(d / "commands.csv", np.column_stack([best.cmd_t, best.duty_pct]), delimiter=",",
                   header="t,d1,d2,d3,d4", comments="", fmt="%.10g")
        (d / "design.json").write_text(json.dumps(doc, indent=2, default=float) + "\n")
    lines = [f"D-optimal thrust-calibration input over {s.duration_s:g} s (--per {per}, "
             f"m = {s.plant.mass_kg:g} kg and Izz = {s.plant.izz_kgm2:g} kg m^2 known; "
             f"{res.evaluated} sequences)",
             f"  {'input':<44} {'log det':>9} {'max sd':>8} {'counts open':>12} {'excursion x,y m':>16}  fits"]
    for e in [*compared, best]:
        lab = e.label if len(e.label) <= 44 else e.label[:41] + "..."
        sd = f"{e.sigma.max():8.2g}" if e.sigma.size and np.all(np.isfinite(e.sigma)) else f"{'-':>8}"
        counts = ",".join(str(k) for k in sorted(e.counts_s))
        lines.append(f"  {lab:<44} {e.logdet:9.3f} {sd} {counts:>12} {e.excursion_m[0]:7.2f},"
                     f"{e.excursion_m[1]:7.2f}  {'yes' if e.feasible else 'NO: ' + e.reason}")
    lines += [f"  best: {best.spec.describe()}",
              f"  wrote {out_folder.path / 'commands.csv'} (play it or simulate it with tpods sim "
              "--input), design.json"]
    return CalibrationDesignReport(res, compared, doc, lines)
