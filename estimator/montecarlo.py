"""Monte Carlo consistency analysis of the EKF (the paper's Figures 9 and 10).

Each run draws m and Izz uniformly within +/- ``spread`` of the nominal values, starts
from a kinematic state drawn from the filter's initial distribution, is simulated
under the shared input with 1 cm / 1 deg pose noise (and optional dropped frames),
and is filtered. Everything runs vectorised across runs and streams along time: the
truth is integrated for all runs at once (:func:`estimator.plant.propagate.rk4_states`,
split at every pose time and command switch like :func:`estimator.plant.model.integrate_zoh`),
the poses are drawn, and one :class:`estimator.filters.vec.VecEKF` filters every run;
only per-time statistics are kept, so memory does not grow with runs x time.

Filter initialisation (method ``ekf``): mean (0, 0, 0, 0, 0, 0, m_nom, Izz_nom) and
standard deviations from the filter settings for the kinematic states and
``spread * nominal / sqrt(3)`` (the standard deviation of the uniform draw) for m and
Izz, so the initial errors match the initial covariance in their first two moments.
Method ``ls-ekf`` starts each run from a batch least-squares fit of the first
``ls_window_s`` seconds (see :func:`ls_start`).

Statistics (``e`` = estimate - truth, yaw error wrapped, ``P`` = filter covariance):

- bias: mean of ``e`` over runs at each time; spread: sample standard deviation;
- filter sigma: ``sqrt(mean over runs of P_ii)`` at each time;
- average NEES ``mean_r e_r^T P_r^-1 e_r`` for the parameters (m, Izz: 2 dof) and the
  full state (8 dof); with R runs, ``R * NEES`` is chi-square with ``R n`` dof when the
  filter is consistent, giving the two-sided 95 % bounds ``chi2.ppf([.025, .975], R n)/R``;
- fraction of final errors inside 3 sigma, per parameter;
- per-run RMSE of m and Izz over every pose time.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field

import numpy as np
from tqdm import tqdm

from common import chi2  # scipy.stats.chi2 without its import cost
from common.constants import PAPER_IZZ_KGM2, PAPER_MASS_KG
from common.errors import UserError
from common.thrust_table import load_thrust_table
from estimator.batch.least_squares import batch_ls
from estimator.filters.ekf import NX, PAPER, EkfConfig
from estimator.filters.vec import VecEKF, shared_schedule
from estimator.plant.inputs import make_input
from estimator.plant.model import PARAM_NAMES, wrench
from estimator.plant.propagate import rk4_states
from estimator.plant.sim import pose_times

NOMINAL_MASS_KG = PAPER_MASS_KG
NOMINAL_IZZ_KGM2 = PAPER_IZZ_KGM2
METHODS = ("ekf", "ls-ekf")
LS_STARTS = ("reuse", "handoff")
"""How ls-ekf starts the filter: ``reuse`` (the paper: at t0 from the LS mean and
covariance, then over the whole run, so the LS window's poses are used twice) or
``handoff`` (the LS estimate and covariance propagated to the end of the window,
then only the later poses: each pose used once)."""

MC_FILTER = PAPER.with_(q_psd=(0.0,) * NX)
"""Default Monte Carlo filter: the paper's settings without process noise (the simulated
parameters are constant, so a consistent filter has none; pass the paper's 1e-4 kg^2/Hz
to see its effect)."""


@dataclass
class McConfig:
    """Monte Carlo settings (SI units).

    ``truth_max_step_s`` is the longest RK4 step of the simulated truth (1/120 s gives
    < 1e-7 m against :func:`estimator.plant.model.integrate_zoh` over 120 s, far below the
    1 cm noise); the full-state NEES (an 8x8 solve per run) is evaluated every
    ``nees_every`` poses (NaN in between), the parameter NEES at every pose.
    """

    runs: int = 500
    spread: float = 0.5
    duration_s: float = 120.0
    input: str = "phase-sine"
    method: str = "ekf"
    seed: int = 0
    pose_rate_hz: float = 120.0
    cmd_rate_hz: float = 50.0
    amplitude_pct: float = 20.0
    omega_rad_s: float = 1.0
    noise_pos_m: float = 0.01
    noise_yaw_rad: float = math.radians(1.0)
    drop: float = 0.0
    truth_max_step_s: float = 1 / 120
    nees_every: int = 6
    ls_window_s: float = 20.0
    ls_start: str = "reuse"
    n_examples: int = 30
    filter: EkfConfig = field(default_factory=lambda: MC_FILTER)

    def __post_init__(self):
        if self.runs < 2:
            raise ValueError("need at least 2 runs")
        if not 0 <= self.spread < 1:
            raise ValueError("spread must lie in [0, 1)")
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {', '.join(METHODS)}")
        if not 0 <= self.drop < 1:
            raise ValueError("drop must lie in [0, 1)")
        if self.ls_start not in LS_STARTS:
            raise ValueError(f"ls_start must be one of {', '.join(LS_STARTS)}")


@dataclass
class McResult:
    """Monte Carlo statistics.

    Attributes:
        t: (N,) time grid, s.
        bias: (N, 8) mean error over runs. std: (N, 8) sample standard deviation.
        sigma: (N, 8) filter sigma, sqrt of the mean variance.
        nees_param, nees_full: (N,) average NEES (2 and 8 dof).
        bounds_param, bounds_full: (2,) two-sided 95 % bounds of the average NEES.
        triggered: (N,) fraction of runs whose update was underweighted.
        truth: (R, 2) drawn m (kg) and Izz (kg m^2).
        final_err, final_sigma: (R, 8) at the last time.
        rmse: (R, 2) RMSE of m and Izz over every pose time.
        ex_err, ex_sigma: (K, N, 2) m and Izz errors and sigmas of the first K runs.
    """

    config: McConfig
    t: np.ndarray
    bias: np.ndarray
    std: np.ndarray
    sigma: np.ndarray
    nees_param: np.ndarray
    nees_full: np.ndarray
    bounds_param: np.ndarray
    bounds_full: np.ndarray
    triggered: np.ndarray
    truth: np.ndarray
    final_err: np.ndarray
    final_sigma: np.ndarray
    rmse: np.ndarray
    ex_err: np.ndarray
    ex_sigma: np.ndarray
    elapsed_s: float = 0.0
    ls_failed: int = 0
    final_cov_param: np.ndarray | None = None
    interrupted: bool = False

    def final_nees_param(self) -> np.ndarray:
        """(R,) NEES of the final (m, Izz) error of every run (2 dof)."""
        e = self.final_err[:, 6:8]
        if self.final_cov_param is None:
            return np.sum((e / self.final_sigma[:, 6:8]) ** 2, axis=1)
        return np.einsum("ri,ri->r", e, np.linalg.solve(self.final_cov_param, e[:, :, None])[:, :, 0])

    def within_3sigma(self) -> np.ndarray:
        """(2,) fraction of runs whose final m and Izz errors lie inside 3 sigma."""
        return np.mean(np.abs(self.final_err[:, 6:8]) <= 3 * self.final_sigma[:, 6:8], axis=0)

    def nees_inside(self, which: str = "param", t_from: float = 0.0) -> float:
        """Fraction of times (>= t_from) whose average NEES lies inside its 95 % bounds."""
        v, b = (self.nees_param, self.bounds_param) if which == "param" else (self.nees_full,
                                                                              self.bounds_full)
        sel = (self.t >= t_from) & np.isfinite(v)
        return float(np.mean((v[sel] >= b[0]) & (v[sel] <= b[1])))

    def summary(self) -> dict:
        """JSON-ready summary (no per-time arrays)."""
        w3 = self.within_3sigma()
        n = len(self.t)
        late = self.t >= 0.1 * self.t[-1]
        return {
            "runs": self.config.runs, "method": self.config.method,
            "duration_s": self.config.duration_s, "input": self.config.input,
            "spread": self.config.spread, "seed": self.config.seed,
            "ls_window_s": self.config.ls_window_s if self.config.method == "ls-ekf" else None,
            "ls_start": self.config.ls_start if self.config.method == "ls-ekf" else None,
            "underweight": self.config.filter.underweight,
            "process_noise": dict(zip(("x", "y", "psi", "u", "v", "r", "mass", "izz"),
                                      self.config.filter.q_psd, strict=True)),
            "poses_per_run": n,
            "final_bias_mass_kg": float(self.bias[-1, 6]),
            "final_bias_izz_kgm2": float(self.bias[-1, 7]),
            "final_std_mass_kg": float(self.std[-1, 6]),
            "final_std_izz_kgm2": float(self.std[-1, 7]),
            "final_sigma_mass_kg": float(self.sigma[-1, 6]),
            "final_sigma_izz_kgm2": float(self.sigma[-1, 7]),
            "within_3sigma_mass": float(w3[0]), "within_3sigma_izz": float(w3[1]),
            "nees_param_mean": float(np.nanmean(self.nees_param)),
            "nees_param_mean_late": float(np.nanmean(self.nees_param[late])),
            "nees_param_bounds": self.bounds_param.tolist(),
            "nees_param_inside_frac": self.nees_inside("param"),
            "nees_param_inside_frac_late": self.nees_inside("param", 0.1 * self.t[-1]),
            "nees_full_mean": float(np.nanmean(self.nees_full)),
            "nees_full_mean_late": float(np.nanmean(self.nees_full[late])),
            "nees_full_bounds": self.bounds_full.tolist(),
            "nees_full_inside_frac": self.nees_inside("full"),
            "nees_full_inside_frac_late": self.nees_inside("full", 0.1 * self.t[-1]),
            "final_nees_param_median": float(np.median(self.final_nees_param())),
            "final_outlier_frac": float(np.mean(self.final_nees_param() > chi2.ppf(0.999, 2))),
            "underweighted_frac": float(np.mean(self.triggered)),
            "rmse_mass_kg_mean": float(np.mean(self.rmse[:, 0])),
            "rmse_izz_kgm2_mean": float(np.mean(self.rmse[:, 1])),
            "ls_failed": self.ls_failed,
            "interrupted": self.interrupted,
            "t_end_s": float(self.t[-1]),
            "elapsed_s": self.elapsed_s,
        }

    def history_table(self) -> tuple[list[str], np.ndarray]:
        """Column names and (N, k) per-time statistics for the CSV."""
        cols = ["t"]
        data = [self.t]
        for j, name in ((6, "mass"), (7, "izz")):
            cols += [f"bias_{name}", f"std_{name}", f"sigma_{name}"]
            data += [self.bias[:, j], self.std[:, j], self.sigma[:, j]]
        cols += ["nees_param", "nees_full", "underweighted_frac"]
        data += [self.nees_param, self.nees_full, self.triggered]
        return cols, np.column_stack(data)


def nees_bounds(runs: int, dof: int, level: float = 0.95) -> np.ndarray:
    """Two-sided ``level`` bounds of the average NEES over ``runs`` runs of ``dof`` dof."""
    a = (1 - level) / 2
    return chi2.ppf([a, 1 - a], runs * dof) / runs


def draw_truth(rng: np.random.Generator, runs: int, spread: float,
               nominal=(NOMINAL_MASS_KG, NOMINAL_IZZ_KGM2)) -> np.ndarray:
    """(runs, 2) masses (kg) and Izz (kg m^2) uniform within +/- spread of nominal."""
    u = rng.uniform(-spread, spread, size=(runs, 2))
    return np.asarray(nominal) * (1.0 + u)


def initial_filter(cfg: McConfig) -> tuple[np.ndarray, np.ndarray]:
    """Filter mean (8,) and covariance (8, 8) used to start every ``ekf`` run."""
    f = cfg.filter
    x0 = np.array(f.x0, float)
    x0[6:8] = (NOMINAL_MASS_KG, NOMINAL_IZZ_KGM2)
    sig = np.array(f.sigma0, float)
    sig[6:8] = np.array([NOMINAL_MASS_KG, NOMINAL_IZZ_KGM2]) * cfg.spread / math.sqrt(3.0)
    if cfg.spread == 0:
        sig[6:8] = np.array(f.sigma0[6:8])
    return x0, np.diag(sig**2)


class TruthStream:
    """Simulated runs advanced in lockstep along the common pose grid.

    ``advance(k)`` integrates every run to ``t[k]`` and returns the true states (R, 6),
    the measured poses (R, 3) (yaw wrapped) and the mask of kept frames (R,).
    """

    def __init__(self, cfg: McConfig, t, cmd_t, thrust_n, truth, s0, rng):
        self.cfg = cfg
        self.t = t
        self.seg_dt, self.seg_thr = shared_schedule(t, cmd_t, thrust_n)
        self.mass, self.izz = truth[:, 0], truth[:, 1]
        f = cfg.filter
        self.params = {"mass": self.mass, "izz": self.izz,
                       **dict(zip(PARAM_NAMES[2:7], f.known, strict=True))}
        self.seg_w = [[wrench(thr, f.arm_m) for thr in seg] for seg in self.seg_thr]
        self.s = np.array(s0, float)
        self.rng = rng
        self.runs = len(truth)
        self._noise_scale = np.array([cfg.noise_pos_m, cfg.noise_pos_m, cfg.noise_yaw_rad])

    def advance(self, k: int):
        if k:
            for dt, w in zip(self.seg_dt[k], self.seg_w[k], strict=True):
                if dt > 0:
                    n = max(1, math.ceil(dt / self.cfg.truth_max_step_s - 1e-9))
                    self.s = rk4_states(self.s, w, dt / n, n, self.params)
        cfg = self.cfg
        noise = self.rng.standard_normal((self.runs, 3)) * self._noise_scale
        pose = self.s[:, :3] + noise
        pose[:, 2] = (pose[:, 2] + math.pi) % (2 * math.pi) - math.pi
        keep = np.ones(self.runs, bool)
        if cfg.drop > 0 and k > 0:
            keep = self.rng.random(self.runs) >= cfg.drop
        return self.s, pose, keep


def make_scenario(cfg: McConfig):
    """Common time grid (N,), command times (Nc,) and thrusts (Nc, 4) N of the Monte Carlo."""
    table = load_thrust_table(None)
    cmd_t, duty = make_input(cfg.input, cfg.duration_s, cfg.cmd_rate_hz, cfg.amplitude_pct,
                             cfg.omega_rad_s, valid_pct=table.duty_range)
    thrust = table.thrust_n(duty)
    t = pose_times(cmd_t[0], cmd_t[-1], cfg.pose_rate_hz)
    return t, cmd_t, thrust


def ls_start(cfg: McConfig, t, cmd_t, thrust_n, truth, s0, seed_seq, progress=None):
    """Batch least squares on the first ``ls_window_s`` seconds of every run.

    Re-simulates that stretch with the same random stream as the filtering pass, so
    the data are identical. Returns ``(x0 (R, 8), P0 (R, 8, 8), failed)``; a run whose
    fit fails or does not converge starts from the ``ekf`` initialisation instead.
    """
    rng = np.random.default_rng(seed_seq)
    stream = TruthStream(cfg, t, cmd_t, thrust_n, truth, s0, rng)
    nw = int(np.searchsorted(t, t[0] + cfg.ls_window_s, side="right"))
    poses = np.empty((cfg.runs, nw, 3))
    keeps = np.empty((cfg.runs, nw), bool)
    for k in range(nw):
        _, poses[:, k], keeps[:, k] = stream.advance(k)
    x0d, P0d = initial_filter(cfg)
    x0 = np.tile(x0d, (cfg.runs, 1))
    P0 = np.tile(P0d, (cfg.runs, 1, 1))
    failed = 0
    f = cfg.filter
    for r in range(cfg.runs):
        keep = keeps[r]
        try:
            res = batch_ls(t[:nw][keep], poses[r][keep], cmd_t, thrust_n,
                           sigma_pos_m=f.sigma_meas[0], sigma_yaw_rad=f.sigma_meas[2],
                           fixed={"arm": f.arm_m, "ct": f.ct, "cr": f.cr, "kb": f.kb,
                                  "ax": f.ax, "ay": f.ay})
            if res.converged and np.all(np.isfinite(res.cov)) and res.z0[6] > 0 and res.z0[7] > 0:
                x0[r] = res.z0
                P0[r] = 0.5 * (res.cov + res.cov.T)
            else:
                failed += 1
        except (UserError, np.linalg.LinAlgError, FloatingPointError):
            failed += 1
        if progress is not None:
            progress(r)
    return x0, P0, failed


def run_montecarlo(cfg: McConfig, progress: bool = False,
                   on_step: Callable[[int], None] | None = None) -> McResult:
    """Run the Monte Carlo (vectorised across runs). ``progress`` shows tqdm bars on stderr."""
    t_start = time.perf_counter()
    t, cmd_t, thrust = make_scenario(cfg)
    ss = np.random.SeedSequence(cfg.seed)
    s_truth, s_init, s_stream = ss.spawn(3)
    truth = draw_truth(np.random.default_rng(s_truth), cfg.runs, cfg.spread)
    x0d, P0d = initial_filter(cfg)
    sig0 = np.sqrt(np.diag(P0d))[:6]
    s0 = np.random.default_rng(s_init).standard_normal((cfg.runs, 6)) * sig0 + x0d[:6]
    ls_failed = 0
    if cfg.method == "ls-ekf":
        bar = tqdm(total=cfg.runs, desc="batch LS", unit="run", disable=not progress,
                   file=None)
        x0, P0, ls_failed = ls_start(cfg, t, cmd_t, thrust, truth, s0, s_stream,
                                     progress=lambda _r: bar.update(1))
        bar.close()
    else:
        x0 = np.tile(x0d, (cfg.runs, 1))
        P0 = P0d
    stream = TruthStream(cfg, t, cmd_t, thrust, truth, s0, np.random.default_rng(s_stream))
    filt = VecEKF(cfg.filter, x0, P0)
    t_skip = t[0] + cfg.ls_window_s if (cfg.method == "ls-ekf" and cfg.ls_start == "handoff") \
        else -math.inf
    n, r = len(t), cfg.runs
    bias = np.empty((n, NX))
    std = np.empty((n, NX))
    sigma = np.empty((n, NX))
    nees_p = np.empty(n)
    nees_f = np.empty(n)
    trig = np.empty(n)
    ke = min(cfg.n_examples, r)
    ex_err = np.empty((ke, n, 2))
    ex_sig = np.empty((ke, n, 2))
    sq = np.zeros((r, 2))
    idx = np.arange(NX)
    bar = tqdm(total=n, desc=f"{cfg.method} x {r} runs", unit="pose", unit_scale=True,
               disable=not progress, mininterval=0.5)
    done = 0  # time steps completed
    interrupted = False
    try:
        for k in range(n):
            s, pose, keep = stream.advance(k)
            if k:
                filt.predict_w(stream.seg_dt[k], stream.seg_w[k])
            filt.update(pose, keep & (t[k] > t_skip))
            x, P = filt.x, filt.P
            e = x.copy()
            e[:, :6] -= s
            e[:, 6:8] -= truth
            e[:, 2] = (e[:, 2] + math.pi) % (2 * math.pi) - math.pi
            var = P[:, idx, idx]
            np.sum(e, axis=0, out=bias[k])
            np.einsum("ri,ri->i", e, e, out=std[k])  # sums; turned into mean / std below
            np.sum(var, axis=0, out=sigma[k])
            if k % cfg.nees_every == 0 or k == n - 1:
                nees_f[k] = np.mean(np.einsum("ri,ri->r", e, np.linalg.solve(P, e[:, :, None])[:, :, 0]))
            else:
                nees_f[k] = np.nan
            a, b, c = P[:, 6, 6], P[:, 6, 7], P[:, 7, 7]
            em, ei = e[:, 6], e[:, 7]
            nees_p[k] = np.mean((c * em * em - 2 * b * em * ei + a * ei * ei) / (a * c - b * b))
            trig[k] = np.mean(filt.triggered)
            ex_err[:, k] = e[:ke, 6:8]
            ex_sig[:, k] = np.sqrt(var[:ke, 6:8])
            sq_k = sq + e[:, 6:8] ** 2
            if (k + 1) % 240 == 0 or k == n - 1:
                bar.update(k + 1 - bar.n)
                if on_step is not None:
                    on_step(k)
            sq, e_last, P_last, done = sq_k, e, P, k + 1
    except KeyboardInterrupt:
        interrupted = True  # keep what was computed: the statistics of the first `done` poses
    bar.close()
    if done == 0:
        raise KeyboardInterrupt
    if done < n:
        t, bias, std, sigma = t[:done], bias[:done], std[:done], sigma[:done]
        nees_p, nees_f, trig = nees_p[:done], nees_f[:done], trig[:done]
        ex_err, ex_sig = ex_err[:, :done], ex_sig[:, :done]
    bias /= r
    std = np.sqrt(np.maximum(std - r * bias**2, 0.0) / (r - 1))
    sigma = np.sqrt(sigma / r)
    final_sigma = np.sqrt(P_last[:, idx, idx])
    return McResult(cfg, t, bias, std, sigma, nees_p, nees_f, nees_bounds(r, 2),
                    nees_bounds(r, NX), trig, truth, e_last, final_sigma, np.sqrt(sq / done),
                    ex_err, ex_sig, time.perf_counter() - t_start, ls_failed,
                    P_last[:, 6:8, 6:8].copy(), interrupted)


def config_dict(cfg: McConfig) -> dict:
    d = asdict(cfg)
    d["filter"] = asdict(cfg.filter)
    return d
