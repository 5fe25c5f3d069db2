"""D-optimal input design over the phase-shifted-sine family, under a workspace bound.

Criterion: ``log det`` of the Fisher information on (m, Izz) with the initial state
marginalised (Schur complement, :mod:`estimator.batch.crlb`), evaluated at an assumed plant.
Candidates ``d_i(t) = mean + A sin(w t + phase_i)`` keep every open duty inside the
thrust table's valid range; a candidate is feasible only if its predicted trajectory
(from rest at the table centre) keeps the module's centre inside the table, less a
margin (and, optionally, keeps the yaw rate below a limit). The search: random candidates, then a Nelder-Mead refinement of the best
few on the feasible set (infeasible points score -inf).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from common.constants import PAPER_IZZ_KGM2, PAPER_MASS_KG
from common.errors import UserError
from common.thrust_table import ThrustTable
from estimator.batch.crlb import CRLBResult, crlb
from estimator.plant.inputs import phase_sine
from estimator.plant.model import PlantParams
from estimator.plant.sim import pose_times


@dataclass(frozen=True)
class SineInput:
    """A member of the phase-shifted-sine family (duty percent, rad/s, rad)."""

    amplitude_pct: float
    omega_rad_s: float
    phases_rad: tuple[float, ...]  # one per valve channel (4 per module)
    mean_pct: float = 50.0

    @classmethod
    def paper(cls, n_channels: int = 4) -> SineInput:
        """The paper's informed input: A = 20 %, w = 1 rad/s, phases (i-1) pi/4 (continuing
        over every module's channels for a structure)."""
        return cls(20.0, 1.0, tuple(i * math.pi / 4 for i in range(n_channels)))

    def commands(self, duration_s: float, cmd_rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
        return phase_sine(duration_s, cmd_rate_hz, self.amplitude_pct, self.omega_rad_s,
                          self.mean_pct, self.phases_rad)

    def describe(self) -> str:
        ph = ", ".join(f"{p:.3f}" for p in self.phases_rad)
        return (f"A = {self.amplitude_pct:.2f} %, w = {self.omega_rad_s:.4f} rad/s, "
                f"mean = {self.mean_pct:.1f} %, phases = ({ph}) rad")


@dataclass
class Evaluation:
    """Score of one command sequence."""

    logdet: float
    crlb: CRLBResult
    excursion_m: tuple[float, float]  # largest |x - x0|, |y - y0| over the run
    feasible: bool
    label: str = ""
    spec: SineInput | None = None
    cmd_t: np.ndarray | None = None
    duty_pct: np.ndarray | None = None

    @property
    def score(self) -> float:
        return self.logdet if self.feasible else -math.inf


@dataclass
class DesignSettings:
    """The design problem: duration, rates, noise, assumed plant and workspace."""

    duration_s: float = 120.0
    cmd_rate_hz: float = 50.0
    pose_rate_hz: float = 120.0
    sigma_pos_m: float = 0.01
    sigma_yaw_rad: float = math.radians(1.0)
    plant: PlantParams = field(default_factory=lambda: PlantParams(PAPER_MASS_KG, PAPER_IZZ_KGM2))
    table_size_m: tuple[float, float] = (2.0, 2.0)
    margin_m: float = 0.0
    max_yaw_rate_rad_s: float | None = None
    structure: Any = None
    """A :class:`common.structure.Structure`: its modules' duties are designed
    together, the thrust is its virtual thrust and the criterion is on (m, Izz, cx, cy)
    less the values its [body] gives as known (no sigma: the estimators fix them);
    ``plant`` then carries the assumed cx, cy."""

    @property
    def names(self) -> tuple[str, ...]:
        if self.structure is None:
            return ("mass", "izz")
        known = self.structure.body.known()
        return tuple(n for n in ("mass", "izz", "cx", "cy") if n not in known)

    @property
    def n_channels(self) -> int:
        return 4 if self.structure is None else self.structure.n_channels

    def duty_range(self, table: ThrustTable) -> tuple[float, float]:
        """The duties every module's table accepts."""
        if self.structure is None:
            return table.duty_range
        return self.structure.duty_range()


def evaluate_commands(cmd_t, duty_pct, table: ThrustTable, settings: DesignSettings,
                      label: str = "", spec: SineInput | None = None) -> Evaluation:
    """D-optimal criterion and workspace check of a duty sequence (start at rest, centre)."""
    hold_t, thrust = ((cmd_t, table.thrust_n(duty_pct)) if settings.structure is None
                      else settings.structure.input_profile(cmd_t, duty_pct))  # valve timing too
    t_pose = pose_times(cmd_t[0], cmd_t[-1], settings.pose_rate_hz)
    c = crlb(t_pose, hold_t, thrust, settings.plant.kwargs(), sigma_pos_m=settings.sigma_pos_m,
             sigma_yaw_rad=settings.sigma_yaw_rad, keep_sensitivities=True, names=settings.names)
    exc = np.abs(c.states[:, :2] - c.states[0, :2]).max(axis=0)
    half = np.asarray(settings.table_size_m, float) / 2 - settings.margin_m
    feasible = bool(np.all(exc <= half)) and math.isfinite(c.logdet)
    if settings.max_yaw_rate_rad_s is not None:
        feasible = feasible and bool(np.abs(c.states[:, 5]).max() <= settings.max_yaw_rate_rad_s)
    return Evaluation(c.logdet, c, (float(exc[0]), float(exc[1])), feasible, label, spec,
                      np.asarray(cmd_t), np.asarray(duty_pct))


def evaluate_sine(spec: SineInput, table: ThrustTable, settings: DesignSettings,
                  label: str = "") -> Evaluation:
    lo, hi = settings.duty_range(table)
    if len(spec.phases_rad) != settings.n_channels:
        raise UserError(f"the input has {len(spec.phases_rad)} phases for {settings.n_channels} "
                        "valve channels")
    if spec.mean_pct - spec.amplitude_pct < lo - 1e-9 or spec.mean_pct + spec.amplitude_pct > hi + 1e-9:
        raise UserError(f"duties {spec.mean_pct - spec.amplitude_pct:g}..{spec.mean_pct + spec.amplitude_pct:g} % "
                        f"leave the table's valid range {lo:g}-{hi:g} %")
    cmd_t, duty = spec.commands(settings.duration_s, settings.cmd_rate_hz)
    return evaluate_commands(cmd_t, duty, table, settings, label or spec.describe(), spec)


def _decode(x: np.ndarray, a_max: float, w_range: tuple[float, float], mean: float) -> SineInput:
    """Unconstrained vector (6,) -> a valid SineInput (amplitude and frequency squashed)."""
    a = a_max / (1 + math.exp(-x[0]))
    lw0, lw1 = math.log(w_range[0]), math.log(w_range[1])
    w = math.exp(lw0 + (lw1 - lw0) / (1 + math.exp(-x[1])))
    ph = tuple(float(np.mod(p, 2 * math.pi)) for p in x[2:])
    return SineInput(a, w, ph, mean)


def _encode(spec: SineInput, a_max: float, w_range: tuple[float, float]) -> np.ndarray:
    def logit(p):
        p = min(max(p, 1e-6), 1 - 1e-6)
        return math.log(p / (1 - p))

    lw0, lw1 = math.log(w_range[0]), math.log(w_range[1])
    return np.array([logit(spec.amplitude_pct / a_max),
                     logit((math.log(spec.omega_rad_s) - lw0) / (lw1 - lw0)), *spec.phases_rad])


@dataclass
class DesignResult:
    best: Evaluation
    paper: Evaluation
    evaluated: int
    history: list[Evaluation]


def search(table: ThrustTable, settings: DesignSettings, *, n_random: int = 48,
           n_refine: int = 2, refine_evals: int = 40, omega_range: tuple[float, float] = (0.2, 4.0),
           mean_pct: float = 50.0, seed: int = 0,
           progress: Callable[[int], None] | None = None) -> DesignResult:
    """Search the phase-shifted-sine family for the largest feasible log det.

    Args:
        table: thrust table (its valid duty range bounds the amplitude).
        settings: duration, rates, noise, assumed plant, workspace.
        n_random: random candidates (amplitude uniform in the valid range, frequency
            log-uniform in ``omega_range``, phases uniform).
        n_refine, refine_evals: Nelder-Mead refinements of the best feasible candidates
            and their evaluation budget each.
        progress: called with 1 after every evaluation (for a progress bar).
    """
    from scipy.optimize import minimize

    lo, hi = settings.duty_range(table)
    n = settings.n_channels
    a_max = min(mean_pct - lo, hi - mean_pct)
    if a_max <= 0:
        raise UserError(f"mean duty {mean_pct:g} % leaves no room inside {lo:g}-{hi:g} %")
    rng = np.random.default_rng(seed)
    history: list[Evaluation] = []

    def ev(spec: SineInput) -> Evaluation:
        e = evaluate_sine(spec, table, settings)
        history.append(e)
        if progress:
            progress(1)
        return e

    paper_spec = SineInput.paper(n)
    paper = evaluate_sine(paper_spec, table, settings, "paper's phase-shifted sine" if n == 4
                          else "phase-shifted sine, phases (i-1) pi/4 over every channel")
    if progress:
        progress(1)
    for _ in range(n_random):
        spec = SineInput(float(rng.uniform(0.2, 1.0) * a_max),
                         float(math.exp(rng.uniform(*np.log(omega_range)))),
                         tuple(rng.uniform(0, 2 * math.pi, n).tolist()), mean_pct)
        ev(spec)
    # the hand-made input competes too: a refinement may start from it, and the design is
    # never worse than it
    ranked = sorted((e for e in [paper, *history] if e.feasible), key=lambda e: -e.score)
    for start in ranked[:n_refine]:
        x0 = _encode(start.spec, a_max, omega_range)

        def neg(x):
            return -ev(_decode(x, a_max, omega_range, mean_pct)).score

        with np.errstate(invalid="ignore"):
            minimize(neg, x0, method="Nelder-Mead",
                     options={"maxfev": refine_evals,
                              "initial_simplex": x0 + 0.3 * np.vstack([np.zeros(n + 2), np.eye(n + 2)])})
    feasible = [e for e in history if e.feasible]
    if paper.feasible:
        import copy

        feasible.append(copy.copy(paper))
    if not feasible:
        raise UserError("no candidate keeps the module inside the table; shorten the duration "
                        "or enlarge the table size")
    best = max(feasible, key=lambda e: e.score)
    best.label = "best phase-shifted sine: " + best.spec.describe()
    return DesignResult(best, paper, len(history) + 1, history)
