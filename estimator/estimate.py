"""The estimator's use cases, one function each: what ``tpods estimate batch`` and
``tpods estimate crlb``, the demo, the reports and notebooks call.

- :func:`estimate_run` estimates mass and Izz (and, by model, friction, yaw bias, tilt)
  of a run by batch least squares (``ls``), the EKF (``ekf``) or the LS-started EKF
  (``ls-ekf``), under a named model or the one a likelihood-ratio test picks
  (``model="auto"``). Returns an :class:`Estimate`; ``to_dict()`` is the JSON object
  ``tpods estimate batch --json`` prints.
- :func:`bound_sequence` is the Cramér-Rao bound of a recorded run or of a planned
  command sequence (:func:`load_sequence`). Returns a :class:`Bound`.
- :func:`filter_config` builds the EKF setting from a preset and :class:`FilterOptions`
  (the filter options of ``estimate batch``, ``estimate live`` and ``estimate montecarlo``).

The functions print nothing and write no file: the command-line modules
(``tpods/cli/estimate*.py``) parse arguments, read inputs, call them and print or write
the results. Errors a user can fix raise :class:`common.errors.UserError` (their text
names the command-line options, as the CLI shows it).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from common.constants import PAPER_IZZ_KGM2, PAPER_MASS_KG
from common.errors import UserError
from common.runfolder import Run, read_run
from common.thrust_table import ThrustTable, load_thrust_table
from estimator.batch.crlb import CRLBResult, crlb, crlb_from_fisher
from estimator.batch.least_squares import BatchResult, parse_window
from estimator.batch.least_squares import estimate_run as least_squares_run
from estimator.batch.model_select import ModelFit, ModelSelection, fit_models, select_model
from estimator.batch.structure_degenerate import refuse_undetermined, refuse_undetermined_run
from estimator.filters.ekf import PRESETS, EkfConfig, FilterEstimate, estimate_filter, initial_rates
from estimator.filters.ekf import STATE_NAMES as FILTER_STATE_NAMES
from estimator.filters.ekf_ext import ExtEkfConfig, ExtEkfResult, estimate_ext
from estimator.plant.inputs import from_commands_csv
from estimator.plant.model import STATE_NAMES
from estimator.plant.parameter_sets import (
    DEFAULT_MODEL,
    MODELS,
    fixed_for,
    model_of,
    resolve_names,
    with_model,
)
from estimator.plant.sim import pose_times

METHODS = ("ls", "ekf", "ls-ekf")
STRUCTURE_ESTIMATE = ("mass", "izz", "cx", "cy")
"""Default unknowns of a structure run (issue 18): mass, Izz about the centre of mass and
the centre of mass (cx, cy) in the tracked frame (m)."""
Window = tuple[float | None, float | None]


# --------------------------------------------------------------------------------------
# filter settings


@dataclass(frozen=True)
class FilterOptions:
    """The filter options of ``estimate batch --method ekf|ls-ekf`` (and live, Monte Carlo).

    ``process_noise`` and ``sigma0`` map a filter state index (``x, y, psi, u, v, r, mass,
    izz``) to its process-noise spectral density or initial standard deviation (SI units);
    they override the preset.
    """

    preset: str = "paper"
    process_noise: Mapping[int, float] = field(default_factory=dict)
    sigma0: Mapping[int, float] = field(default_factory=dict)
    underweight: float = 0.0
    uw_trigger: float = 1.0
    ls_window_s: float = 20.0
    ls_start: str = "reuse"


def filter_config(opts: FilterOptions, base: EkfConfig | None = None, *,
                  sigma_pos_m: float | None = None, sigma_yaw_rad: float | None = None,
                  fixed: Mapping[str, float] | None = None) -> EkfConfig:
    """The EKF setting: ``base`` (default the preset) with the options, the measurement
    sigmas and the known parameters (``arm, ct, cr, kb, ax, ay``) applied."""
    cfg = base if base is not None else PRESETS[opts.preset]
    q = list(cfg.q_psd)
    for i, v in opts.process_noise.items():
        q[i] = v
    s0 = list(cfg.sigma0)
    for i, v in opts.sigma0.items():
        s0[i] = v
    meas = list(cfg.sigma_meas)
    if sigma_pos_m is not None:
        meas[0] = meas[1] = sigma_pos_m
    if sigma_yaw_rad is not None:
        meas[2] = sigma_yaw_rad
    kw: dict[str, Any] = {}
    for k, v in (fixed or {}).items():
        if k == "arm":
            kw["arm_m"] = v
        elif k in ("ct", "cr", "kb", "ax", "ay"):
            kw[k] = v
        else:
            raise UserError(f"--fixed {k}: the filters estimate mass and izz; fix only arm, ct, "
                            "cr, kb, ax, ay")
    return cfg.with_(q_psd=tuple(q), sigma0=tuple(s0), sigma_meas=tuple(meas),
                     underweight=opts.underweight, uw_trigger=opts.uw_trigger, **kw)


# --------------------------------------------------------------------------------------
# estimate a run


@dataclass
class Estimate:
    """Result of :func:`estimate_run`.

    ``method`` and ``model`` as used (``model`` is the chosen one under ``auto``, or
    ``"custom"`` for a parameter set no model names); ``run`` the run as estimated (the
    window applied). Exactly one of ``batch`` (``ls``), ``filter`` (``ekf``/``ls-ekf``,
    ideal model) and ``ext`` (``ekf``/``ls-ekf``, extended model; ``ext_ls`` its LS start)
    is set. ``selection`` is the ``auto`` model selection, ``start_note`` how the LS fit
    was started when a staged fit gave the start; ``config`` and ``x0`` the filter's setting
    and start; ``crlb`` the bound at the truth (``ls`` on a simulated run).
    """

    method: str
    model: str
    run: Run
    data: dict[str, Any]
    batch: BatchResult | None = None
    filter: FilterEstimate | None = None
    ext: ExtEkfResult | None = None
    ext_ls: BatchResult | None = None
    selection: ModelSelection | None = None
    start_note: str | None = None
    config: EkfConfig | ExtEkfConfig | None = None
    x0: np.ndarray | None = None
    crlb: CRLBResult | None = None

    def to_dict(self) -> dict[str, Any]:
        """The JSON object of ``tpods estimate batch --json`` (same keys, same order)."""
        return dict(self.data)

    @property
    def has_truth(self) -> bool:
        return "truth_mass_kg" in self.data

    @property
    def converged(self) -> bool:
        """False when the batch fit did not converge, a filter diverged or a filter's
        parameter learnt nothing from the run."""
        if self.batch is not None:
            return bool(self.batch.converged)
        if self.filter is not None:
            return self.filter.converged
        return not self.ext.diverged


def as_window(window: Window | str | None) -> Window:
    """``None``, ``"T0:T1"`` or ``(t0, t1)`` -> ``(t0, t1)`` (raises UserError when bad)."""
    if window is None or isinstance(window, str):
        return parse_window(window)
    t0, t1 = window
    if t0 is not None and t1 is not None and t1 <= t0:
        raise UserError(f"window end must follow its start, got {t0}:{t1}")
    return t0, t1


def _windowed(run: Run, window: Window) -> Run:
    return run.window(*window) if window != (None, None) else run


def _truth(run: Run) -> tuple[float, float] | None:
    """(mass, izz) of the run's truth (a simulated run), else None."""
    truth = run.truth or {}
    if "mass_kg" not in truth or "izz_kgm2" not in truth:
        return None
    return float(truth["mass_kg"]), float(truth["izz_kgm2"])


def _start_at(fit: ModelFit, initial: dict[str, float], note: str | None
              ) -> tuple[dict[str, float], str | None]:
    """Start the batch fit at a staged fit's optimum (when it converged)."""
    r = fit.result
    if r.converged and np.all(np.isfinite(r.z0)):
        return (dict(zip(STATE_NAMES + tuple(r.names), r.z0.tolist(), strict=True)),
                f"started at the staged fit's optimum ({fit.start})")
    return initial, note


def _select_structure_model(inputs, *, window, clamp, names, fixed, initial, alpha,
                            sigma_pos_m, sigma_yaw_rad, log):
    """``--model auto`` on a structure: the nested models (ideal, friction, friction+tilt)
    each with the structure's other unknowns (cx, cy), fitted from the structure's start
    and chosen by likelihood-ratio tests (:func:`select_model`). Returns the selection, the
    chosen model, its names and fixed values, and the start at its optimum."""
    run, table = inputs
    wrun = _windowed(run, as_window(window))
    cmd_t, thrust = wrun.thrust_profile(table, clamp=clamp)
    extra = tuple(n for n in names if n not in ("mass", "izz"))
    start = {**{k: v for k, v in run.structure.initial_guess().items() if k in names},
             **initial}
    selection = select_model(wrun.pose_t, wrun.pose, cmd_t, thrust, alpha=alpha,
                             fixed={k: v for k, v in fixed.items() if k not in names},
                             initial=start, extra_names=extra, sigma_pos_m=sigma_pos_m,
                             sigma_yaw_rad=sigma_yaw_rad)
    chosen = selection.chosen
    if log is not None:
        log(f"model selection on {wrun.path} (--model auto, with {', '.join(extra)} in every "
            "model):")
        for line in selection.table_lines():
            log(line)
    names, fixed = with_model(chosen, names, fixed)
    initial, note = _start_at(selection.fits[chosen], dict(initial), None)
    return selection, chosen, names, fixed, initial, note


def _is_structure_run(run: Run | str | Path, structure) -> bool:
    """True for a structure run: ``structure`` given, the Run has one, or its folder holds
    structure.toml (known before the run is read)."""
    if structure is not None:
        return True
    if isinstance(run, Run):
        return run.structure is not None
    return (Path(run) / "structure.toml").is_file()


@dataclass(frozen=True)
class BodyKnowledge:
    """What a structure's ``[body]`` table makes of the unknowns (:func:`body_knowledge`).

    ``names`` the parameters to estimate; ``fixed`` the fixed values (the caller's, plus
    the ``known`` ones); ``known`` the values taken as known from structure.toml (fixed at
    them: a value without a sigma, or a prior's mean when its parameter is not estimated);
    ``priors`` the Gaussian priors ``name -> (mean, sigma)`` on estimated parameters.
    """

    names: tuple[str, ...]
    fixed: Mapping[str, float]
    known: Mapping[str, float]
    priors: Mapping[str, tuple[float, float]]
    source: str = "structure.toml"

    def to_dict(self) -> dict[str, Any]:
        """``known_from_structure`` (name -> value) and ``prior_from_structure`` (name ->
        mean and sigma), SI units (kg, kg m^2, m): keys of the estimate's JSON."""
        return {"known_from_structure": dict(self.known),
                "prior_from_structure": {n: {"mean": m, "sigma": s}
                                         for n, (m, s) in self.priors.items()}}

    def prior_vector(self, names: Sequence[str]) -> tuple[np.ndarray, np.ndarray] | None:
        """``(zbar, Pbar)`` over the state ``(x, y, psi, u, v, r, *names)`` for
        :func:`estimator.batch.least_squares.batch_ls`: the priors' means and variances,
        every other entry diffuse (infinite variance); None without priors on ``names``."""
        if not any(n in self.priors for n in names):
            return None
        n = 6 + len(names)
        zbar, P = np.zeros(n), np.diag(np.full(n, np.inf))
        for j, name in enumerate(names):
            if name in self.priors:
                zbar[6 + j], P[6 + j, 6 + j] = self.priors[name][0], self.priors[name][1] ** 2
        return zbar, P


def _structure_of(run: Run | str | Path, structure):
    """The Structure of a structure run (``structure`` given, the Run's or its folder's)."""
    from common.structure import Structure

    if isinstance(structure, Structure):
        return structure
    if structure is not None:
        return Structure.load(structure)
    if isinstance(run, Run):
        return run.structure
    return Structure.load(Path(run) / "structure.toml")


def body_knowledge(structure, estimate: Sequence[str] | None,
                   fixed: Mapping[str, float]) -> BodyKnowledge:
    """The unknowns of a structure run from its ``[body]`` (issue 18, partly known
    properties): a known value (no sigma, or sigma 0) is fixed, a value with a sigma is a
    Gaussian prior. ``estimate`` (None: :data:`STRUCTURE_ESTIMATE`) and ``fixed`` are the
    caller's and win: a known value named in ``estimate`` is estimated (the fit starts at
    it), one in ``fixed`` takes that value. A prior whose parameter is not estimated fixes
    it at the prior's mean. Raises UserError when nothing is left to estimate."""
    body = structure.body
    known, priors = body.known(), body.priors()
    if estimate is None:
        names = tuple(n for n in STRUCTURE_ESTIMATE if n not in fixed and n not in known)
    else:
        names = tuple(estimate)
    taken = {n: v for n, v in known.items() if n not in names and n not in fixed}
    taken.update({n: m for n, (m, _) in priors.items() if n not in names and n not in fixed})
    used = {n: priors[n] for n in names if n in priors}
    if not names:
        from_body = [n for n in STRUCTURE_ESTIMATE if n in known and n not in fixed]
        from_opt = [n for n in STRUCTURE_ESTIMATE if n in fixed]
        why = "; ".join(w for w in (
            f"[body] gives {', '.join(from_body)} as known (no sigma)" if from_body else "",
            f"--fixed gives {', '.join(from_opt)}" if from_opt else "") if w)
        raise UserError(f"{structure.source}: nothing left to estimate: {why}; name what to "
                        "estimate with --estimate (e.g. --estimate mass), or give a [body] "
                        "value a sigma to make it a prior")
    return BodyKnowledge(names, {**taken, **fixed}, taken, used, str(structure.source))


def estimate_run(run: Run | str | Path, table: ThrustTable | str | Path | None = None, *, method: str = "ls",
                 model: str | None = None, window: Window | str | None = None,
                 clamp: bool = False, estimate: Sequence[str] | None = ("mass", "izz"),
                 fixed: Mapping[str, float] | None = None,
                 initial: Mapping[str, float] | None = None, sigma_pos_m: float = 0.01,
                 sigma_yaw_rad: float = math.radians(1.0), tol: float = 1e-8,
                 max_iter: int = 50, select_alpha: float = 1e-3,
                 filter_options: FilterOptions | None = None,
                 log: Callable[[str], None] | None = None,
                 structure: Any = None) -> Estimate:
    """Estimate a run's parameters: the use case of ``tpods estimate batch``.

    Args:
        run: the run (:func:`common.runfolder.read_run`) or its folder (read after the
            options are checked).
        table: thrust table or its TOML file (default the paper's Table 2); ``clamp``
            clamps duties into its valid range instead of refusing them.
        method: ``ls`` (batch least squares, the paper's Algorithm 1), ``ekf`` or ``ls-ekf``.
        model: ``ideal``, ``friction``, ``friction+tilt`` (sets ``estimate`` and ``fixed``),
            ``auto`` (likelihood-ratio selection at level ``select_alpha``) or None (the
            parameters ``estimate`` with ``fixed``).
        window: poses with ``t0 <= t <= t1`` only, as ``(t0, t1)`` or ``"T0:T1"``.
        initial: initial guess by name (``x, y, psi, u, v, r, mass, izz, ct, ...``).
        sigma_pos_m, sigma_yaw_rad: measurement noise.
        tol, max_iter: the batch fit's convergence threshold and iteration cap per stage.
        filter_options: the filters' setting (default the paper's preset).
        log: receives the model-selection table under ``model="auto"`` and, after a batch
            fit, one ``tpods: warning: ...`` line per implausible residual (RMS far from the
            stated noise: :func:`estimator.batch.least_squares.residual_warnings`; also in
            the result's ``warnings``). Default: dropped.
        structure: a :class:`common.structure.Structure` or its TOML file: the run is a
            structure run (also when its folder holds structure.toml). ``estimate=None``
            then means :data:`STRUCTURE_ESTIMATE` less the ``fixed`` names (else mass,
            izz); ``model`` ``friction``/``friction+tilt`` adds its parameters to them and
            ``auto`` selects among the three with cx, cy in each; every method; the JSON gains
            ``com_x_m``, ``com_y_m`` and ``izz_origin_kgm2`` (Izz about the tracked origin,
            ``izz + m (cx^2 + cy^2)``) with their sigmas. A structure run that cannot
            determine its unknowns raises UserError naming them
            (:mod:`estimator.batch.structure_degenerate`).
            ``table`` then replaces Table 2 for the modules without their own table.

    Raises UserError for a bad window, option or run.
    """
    if method not in METHODS:
        raise UserError(f"method must be one of {', '.join(METHODS)}")
    fixed = dict(fixed or {})
    is_structure = _is_structure_run(run, structure)
    structure_model = None  # a structure's friction/tilt model: its parameters join the unknowns
    if is_structure:
        # friction/tilt join the unknowns; auto selects among them with cx, cy in each
        structure_model = model if model not in (None, DEFAULT_MODEL) else None
        model = None
        knowledge = body_knowledge(_structure_of(run, structure), estimate, fixed)
        estimate, fixed = knowledge.names, dict(knowledge.fixed)
    else:
        knowledge = None
    names = tuple(estimate) if estimate is not None else ("mass", "izz")
    if structure_model not in (None, "auto"):
        names, fixed = with_model(structure_model, names, fixed)
    initial = dict(initial or {})
    opts = filter_options or FilterOptions()
    if method == "ls" and max_iter < 1:
        raise UserError("--max-iter must be at least 1")
    source = [run, table]

    def inputs() -> tuple[Run, ThrustTable]:
        """The run and the table, read when first needed (after the option checks)."""
        if len(source) == 2:  # first call
            if not isinstance(source[0], Run):
                source[0] = read_run(source[0], structure=structure)
            elif structure is not None:
                source[0] = _with_structure(source[0], structure)
            if source[0].structure is not None and source[1] is not None:
                source[0].structure.check_table_option()
            source.append(True)
        if not isinstance(source[1], ThrustTable):
            source[1] = load_thrust_table(source[1])
        return source[0], source[1]

    selection = None
    note = None
    if structure_model == "auto":
        if not 0 < select_alpha < 1:
            raise UserError("--select-alpha must lie in (0, 1)")
        selection, structure_model, names, fixed, initial, note = _select_structure_model(
            inputs(), window=window, clamp=clamp, names=names, fixed=fixed, initial=initial,
            alpha=select_alpha, sigma_pos_m=sigma_pos_m, sigma_yaw_rad=sigma_yaw_rad, log=log)
    if model is None:
        model = structure_model or model_of(names) or "custom"
    else:
        if model == "auto":
            if not 0 < select_alpha < 1:
                raise UserError("--select-alpha must lie in (0, 1)")
            run, table = inputs()
            wrun = _windowed(run, as_window(window))
            cmd_t, thrust = wrun.thrust_profile(table, clamp=clamp)
            selection = select_model(wrun.pose_t, wrun.pose, cmd_t, thrust, alpha=select_alpha,
                                     fixed=dict(fixed), sigma_pos_m=sigma_pos_m,
                                     sigma_yaw_rad=sigma_yaw_rad)
            model = selection.chosen
            if log is not None:
                log(f"model selection on {wrun.path} (--model auto):")
                for line in selection.table_lines():
                    log(line)
            initial, note = _start_at(selection.fits[model], initial, note)
        names = resolve_names(model, names)
        fixed = fixed_for(model, fixed)
        if method != "ls" and model != DEFAULT_MODEL:
            return _extended_filter(inputs, method=method, model=model, window=window,
                                    clamp=clamp, names=names, fixed=fixed, initial=initial,
                                    sigma_pos_m=sigma_pos_m, sigma_yaw_rad=sigma_yaw_rad, tol=tol,
                                    max_iter=max_iter, opts=opts, selection=selection)
        if method == "ls" and model != DEFAULT_MODEL and selection is None:
            # fit the nested smaller models first: the larger fit then starts at (and can only
            # improve on) their optimum, which is more robust than the paper's start alone
            run, table = inputs()
            wrun = _windowed(run, as_window(window))
            cmd_t, thrust = wrun.thrust_profile(table, clamp=clamp)
            order = list(MODELS)
            fits = fit_models(wrun.pose_t, wrun.pose, cmd_t, thrust, order[:order.index(model) + 1],
                              fixed={k: v for k, v in fixed.items() if k not in names},
                              initial=initial, sigma_pos_m=sigma_pos_m,
                              sigma_yaw_rad=sigma_yaw_rad)
            initial, note = _start_at(fits[model], initial, note)
    if method != "ls" and is_structure:  # the extended filter carries cx, cy (issue 18)
        return _extended_filter(inputs, method=method, model=model, window=window,
                                clamp=clamp, names=names, fixed=fixed, initial=initial,
                                sigma_pos_m=sigma_pos_m, sigma_yaw_rad=sigma_yaw_rad, tol=tol,
                                max_iter=max_iter, opts=opts, selection=selection,
                                knowledge=knowledge)
    if method != "ls":
        return _ideal_filter(inputs, method=method, model=model, window=window, clamp=clamp,
                             names=names, fixed=fixed, initial=initial, sigma_pos_m=sigma_pos_m,
                             sigma_yaw_rad=sigma_yaw_rad, tol=tol, max_iter=max_iter, opts=opts,
                             selection=selection, note=note, log=log)
    return _least_squares(inputs, model=model, window=window, clamp=clamp, names=names,
                          fixed=fixed, initial=initial, sigma_pos_m=sigma_pos_m,
                          sigma_yaw_rad=sigma_yaw_rad, tol=tol, max_iter=max_iter,
                          selection=selection, note=note, log=log, knowledge=knowledge)


def _least_squares(inputs, *, model, window, clamp, names, fixed, initial, sigma_pos_m,
                   sigma_yaw_rad, tol, max_iter, selection, note, log=None,
                   knowledge: BodyKnowledge | None = None) -> Estimate:
    run, table = inputs()
    window = as_window(window)
    prior = None
    if run.structure is not None:
        # a structure's start: its geometry (or its [body] values), not the paper's module
        guess = {k: v for k, v in run.structure.initial_guess().items()
                 if k in names and k not in initial}
        if guess:
            initial = {**guess, **initial}
            body = run.structure.body
            from_body = set(guess) & (set(body.known()) | set(body.priors()))
            src = ("geometry" if not from_body else
                   "[body] values" if from_body == set(guess) else "[body] values and geometry")
            note = note or (f"started from the structure's {src}: " + ", ".join(
                f"{k} {v:.4g}" for k, v in guess.items()))
        if knowledge is not None:  # [body] values with a sigma: a Gaussian prior
            prior = knowledge.prior_vector(names)
    res = least_squares_run(run, table, window, clamp=clamp, names=names, fixed=fixed,
                            initial=initial, sigma_pos_m=sigma_pos_m, sigma_yaw_rad=sigma_yaw_rad,
                            tol=tol, max_iter=max_iter,
                            thrust_uncertainty=run.structure is None, prior=prior)
    if run.structure is not None:
        # a structure run that cannot determine its unknowns is refused, naming them
        refuse_undetermined(res, _windowed(run, window).thrust_profile(table, clamp=clamp)[1],
                            str(run.path), fixed=tuple(fixed), structure=run.structure)
        _structure_consider(res, _windowed(run, window), table, clamp, sigma_pos_m, sigma_yaw_rad)
    if log is not None:
        for w in res.warnings:
            log(f"tpods: warning: {w}")
        if res.cov_thrust is None and res.thrust_note:
            log(f"tpods: warning: {res.thrust_note}")
    out: dict[str, Any] = {"method": "ls", "run": str(run.path)}
    out.update(res.to_dict())
    out["model"] = model
    if run.structure is not None:
        out.update(structure_keys(res, run))
    if knowledge is not None:
        out.update(knowledge.to_dict())
    if note:
        out["start"] = note
    if selection is not None:
        out["model_selection"] = selection.to_dict()
    wrun = _windowed(run, window)
    est = Estimate("ls", model, wrun, out, batch=res, selection=selection, start_note=note)
    try:
        tm, ti = float(run.truth["mass_kg"]), float(run.truth["izz_kgm2"])
    except (KeyError, TypeError, ValueError):
        return est
    out.update({"truth_mass_kg": tm, "truth_izz_kgm2": ti,
                "mass_error_kg": res.mass_kg - tm, "izz_error_kgm2": res.izz_kgm2 - ti,
                "mass_rel_error": (res.mass_kg - tm) / tm, "izz_rel_error": (res.izz_kgm2 - ti) / ti})
    truth = run.truth
    if {"mass", "izz"} <= set(res.names):
        # the bound of this very run at the truth, for the efficiency check
        cmd_t, thrust = wrun.thrust_profile(table, clamp=clamp)
        s0 = truth.get("initial_state") if wrun.pose_t[0] == run.pose_t[0] else None
        tp = {k: float(truth.get(k2, d)) for k, k2, d in (
            ("mass", "mass_kg", 0), ("izz", "izz_kgm2", 0), ("arm", "arm_m", 0.05),
            ("ct", "ct", 0), ("cr", "cr", 0), ("kb", "kb", 0), ("ax", "ax", 0), ("ay", "ay", 0),
            ("cx", "cx", 0), ("cy", "cy", 0))}
        if s0 is None:
            s0 = res.z0[:6]
        try:
            c = crlb(wrun.pose_t, cmd_t, thrust, tp, s0=s0, names=res.names,
                     sigma_pos_m=sigma_pos_m, sigma_yaw_rad=sigma_yaw_rad)
            out["crlb_mass_sigma_kg"] = c.mass_sigma_kg
            out["crlb_izz_sigma_kgm2"] = c.izz_sigma_kgm2
            for n, sg in zip(c.names, c.sigma, strict=True):
                if n in ("cx", "cy"):
                    out[f"crlb_{n}_sigma"] = float(sg)
            est.crlb = c
        except (UserError, ValueError, np.linalg.LinAlgError):
            pass
    return est


def _with_structure(run: Run, structure) -> Run:
    """``run`` read as a structure run of ``structure`` (a Structure or its TOML file)."""
    from common.structure import Structure

    s = structure if isinstance(structure, Structure) else Structure.load(structure)
    if run.duty_pct is not None and run.duty_pct.shape[-1] != s.n_channels:
        raise UserError(f"{run.path / 'commands.csv'}: {run.duty_pct.shape[-1]} duty columns; "
                        f"structure {s.name!r} has {s.n_channels} channels")
    return replace(run, structure=s)


def _structure_consider(res: BatchResult, run: Run, table: ThrustTable, clamp: bool,
                        sigma_pos_m: float, sigma_yaw_rad: float) -> None:
    """The thrust-table part of a structure fit's covariance: every module's table
    uncertainty through the virtual thrusts (:meth:`common.runfolder.Run.thrust_sensitivity`),
    as :func:`estimator.batch.least_squares.estimate_run` does for one module."""
    from estimator.batch.consider import NO_UNCERTAINTY, THRUSTS_GIVEN, batch_consider

    if not np.all(np.isfinite(res.sigma)):
        return  # an uninformative fit: reported as such
    if run.thrust_n is not None:
        res.thrust_note = THRUSTS_GIVEN
        return
    sens = run.thrust_sensitivity(table, clamp=clamp)
    if sens is None or sens.empty:
        res.thrust_note = NO_UNCERTAINTY
        return
    c = batch_consider(res, run.cmd_t, sens, sigma_pos_m=sigma_pos_m, sigma_yaw_rad=sigma_yaw_rad)
    res.add_thrust_covariance(c.cov_thrust, c.names)
    res.thrust_note = ("sigma = measurement noise + the modules' thrust table uncertainty "
                       f"({', '.join(c.names)})")


def structure_keys(res: BatchResult, run: Run) -> dict[str, Any]:
    """The structure keys of ``estimate batch --json``: the centre of mass ``com_x_m``,
    ``com_y_m`` (m, tracked frame) with sigmas, and ``izz_origin_kgm2`` = Izz about the
    tracked origin ``izz + m (cx^2 + cy^2)`` (kg m^2) with its sigma from the covariance
    (first order); truth errors on a simulated run. Sigma 0 for a fixed value."""
    return com_keys(res.params, res.names, res.cov, run)


def com_keys(values: Mapping[str, float], names: Sequence[str], cov: np.ndarray,
             run: Run) -> dict[str, Any]:
    """The keys of :func:`structure_keys` from any estimate: ``values`` every parameter's
    value (mass, izz, cx, cy; estimated or fixed), ``names`` the estimated ones and ``cov``
    the covariance of the state ``(x, y, psi, u, v, r, *names)`` (a batch fit's, or a
    filter's final P). Sigma 0 for a fixed value."""
    m, izz, cx, cy = (float(values[k]) for k in ("mass", "izz", "cx", "cy"))
    idx = {n: 6 + i for i, n in enumerate(names)}
    cov = np.asarray(cov, float)
    sig = {n: float(math.sqrt(max(cov[idx[n], idx[n]], 0.0))) if n in idx else 0.0
           for n in ("cx", "cy")}
    grad = {"mass": cx * cx + cy * cy, "izz": 1.0, "cx": 2 * m * cx, "cy": 2 * m * cy}
    g = np.zeros(len(cov))
    for n, v in grad.items():
        if n in idx:
            g[idx[n]] = v
    out: dict[str, Any] = {
        "structure": run.structure.name,
        "com_x_m": cx, "com_x_sigma_m": sig["cx"], "com_y_m": cy, "com_y_sigma_m": sig["cy"],
        "izz_origin_kgm2": izz + m * (cx * cx + cy * cy),
        "izz_origin_sigma_kgm2": float(math.sqrt(max(float(g @ cov @ g), 0.0)))}
    truth = run.truth or {}
    if "mass_kg" in truth:
        tcx, tcy = float(truth.get("cx", 0.0)), float(truth.get("cy", 0.0))
        out.update({"truth_com_x_m": tcx, "truth_com_y_m": tcy,
                    "com_x_error_m": cx - tcx, "com_y_error_m": cy - tcy})
    return out


def filter_thrust_budget(out: dict[str, Any], run: Run, table: ThrustTable, *, clamp: bool,
                         names: Sequence[str], fixed: Mapping[str, float],
                         final: Mapping[str, float], sigma_pos_m: float,
                         sigma_yaw_rad: float) -> BatchResult | None:
    """Make a filter's ``mass_sigma_kg``/``izz_sigma_kgm2`` in ``out`` the TOTAL (noise +
    thrust table), with the budget keys of a batch estimate beside them.

    The thrust part is the batch consider covariance (:mod:`estimator.batch.consider`) of
    the same poses and commands, linearised at the least-squares optimum reached from the
    filter's final estimate ``final``: a filter's constant-parameter estimate is, to first
    order, the least-squares estimate of the data it has seen, so a thrust-table error
    moves both alike (exactly so for a common scale error, which moves m and Izz by the
    same fraction whatever the weighting of the data). The noise part stays the filter's
    own. Returns the fit used, or None when the table states no uncertainty or thrusts.csv
    gives the thrusts (``out["thrust_uncertainty"]["note"]`` then says so).
    """
    from estimator.batch.consider import NO_UNCERTAINTY, THRUSTS_GIVEN

    out["mass_sigma_noise_kg"] = out.get("mass_sigma_kg")
    out["izz_sigma_noise_kgm2"] = out.get("izz_sigma_kgm2")
    out["mass_sigma_thrust_kg"] = 0.0
    out["izz_sigma_thrust_kgm2"] = 0.0
    if run.structure is not None:
        sens = run.thrust_sensitivity(table, clamp=clamp) if run.thrust_n is None else None
        note = (THRUSTS_GIVEN if run.thrust_n is not None else
                NO_UNCERTAINTY if sens is None or sens.empty else "")
    else:
        note = (THRUSTS_GIVEN if run.thrust_n is not None else
                NO_UNCERTAINTY if not table.states_uncertainty else "")
    res = None
    if not note:
        start = {k: float(v) for k, v in final.items()
                 if k in names and math.isfinite(v) and (k not in ("mass", "izz") or v > 0)}
        try:
            res = least_squares_run(run, table, (None, None), clamp=clamp, names=tuple(names),
                                    fixed=dict(fixed), initial=start, sigma_pos_m=sigma_pos_m,
                                    sigma_yaw_rad=sigma_yaw_rad,
                                    thrust_uncertainty=run.structure is None)
            if run.structure is not None:
                _structure_consider(res, run, table, clamp, sigma_pos_m, sigma_yaw_rad)
        except UserError as exc:
            note = f"the thrust part could not be computed ({exc}); sigma covers noise only"
        else:
            if res.cov_thrust is None or not res.converged:
                note = ("the thrust part could not be computed (the least-squares fit at the "
                        "filter's estimate did not converge); sigma covers noise only")
                res = None
    if res is not None:
        st = res.sigma_thrust
        for name, unit in (("mass", "kg"), ("izz", "kgm2")):
            if name in res.names and out.get(f"{name}_sigma_{unit}") is not None:
                t = float(st[6 + res.names.index(name)])
                out[f"{name}_sigma_thrust_{unit}"] = t
                out[f"{name}_sigma_{unit}"] = math.hypot(out[f"{name}_sigma_noise_{unit}"], t)
        note = (res.thrust_note + "; the thrust part from the least-squares linearisation of "
                "the same data")
    out["thrust_uncertainty"] = {"included": res is not None,
                                 "terms": list(res.thrust_terms) if res is not None else [],
                                 "note": note}
    return res


def _ideal_filter(inputs, *, method, model, window, clamp, names, fixed, initial,
                  sigma_pos_m, sigma_yaw_rad, tol, max_iter, opts, selection, note,
                  log=None) -> Estimate:
    if names != ("mass", "izz"):
        raise UserError("the filters estimate exactly mass and izz (drop --estimate or use "
                        "--method ls)")
    run, table = inputs()
    run = _windowed(run, as_window(window))
    cmd_t, thrust = run.thrust_profile(table, clamp=clamp)
    cfg = filter_config(opts, sigma_pos_m=sigma_pos_m, sigma_yaw_rad=sigma_yaw_rad, fixed=fixed)
    bad = [k for k in initial if k not in FILTER_STATE_NAMES]
    if bad:
        raise UserError(f"--initial {', '.join(bad)}: the filters start only x, y, psi, u, v, r, "
                        "m, izz (give known friction/tilt with --fixed)")
    x0 = np.array(cfg.x0, dtype=float)
    # start at the first pose, with velocities from a line fit of the first 0.25 s (the
    # run or window need not begin at rest), unless the initial guess says otherwise
    x0[:3] = run.pose[0]
    if method == "ekf" and not {"u", "v", "r"} & set(initial):
        rates, rsig = initial_rates(run.pose_t, run.pose)
        if np.all(np.isfinite(rsig)):
            x0[3:6] = rates
            s0 = np.array(cfg.sigma0)
            s0[3:6] = np.maximum(s0[3:6], 3 * rsig)
            cfg = cfg.with_(sigma0=tuple(s0.tolist()))
    for k, v in initial.items():
        x0[FILTER_STATE_NAMES.index(k)] = v
    if x0[6] <= 0 or x0[7] <= 0:
        raise UserError("initial mass and izz must be positive")
    ls_kwargs: dict[str, Any] = {}
    if method == "ls-ekf":
        ls_kwargs = {"tol": tol, "max_iter": max_iter}
        if initial:
            ls_kwargs["initial"] = initial
    try:
        fe = estimate_filter(run.pose_t, run.pose, cmd_t, thrust, method, cfg,
                             x0=x0 if method == "ekf" else None, ls_window_s=opts.ls_window_s,
                             ls_start=opts.ls_start, ls_kwargs=ls_kwargs)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    r = fe.result
    if log is not None:  # plausibility (issue 16): as after a batch fit
        for w in ([fe.no_information + "; not converged"] if fe.no_information else []) + fe.warnings:
            log(f"tpods: warning: {w}")
    out: dict[str, Any] = {"run": str(run.path)}
    out.update(fe.to_dict())
    filter_thrust_budget(out, run, table, clamp=clamp, names=("mass", "izz"), fixed=fixed,
                         final={"mass": r.mass_kg, "izz": r.izz_kgm2}, sigma_pos_m=sigma_pos_m,
                         sigma_yaw_rad=sigma_yaw_rad)
    if log is not None and not out["thrust_uncertainty"]["included"]:
        log(f"tpods: warning: {out['thrust_uncertainty']['note']}")
    out["settings"] = {"preset": opts.preset, "q_psd": list(cfg.q_psd),
                       "sigma0": list(cfg.sigma0), "x0": x0.tolist(),
                       "sigma_meas": list(cfg.sigma_meas), "underweight": cfg.underweight,
                       "uw_trigger": cfg.uw_trigger}
    if (truth := _truth(run)) is not None:
        tm, ti = truth
        rm, ri = r.rmse(tm, ti)
        out.update({"truth_mass_kg": tm, "truth_izz_kgm2": ti,
                    "mass_error_kg": r.mass_kg - tm, "izz_error_kgm2": r.izz_kgm2 - ti,
                    "mass_rel_error": (r.mass_kg - tm) / tm,
                    "izz_rel_error": (r.izz_kgm2 - ti) / ti,
                    "rmse_mass_kg": rm, "rmse_izz_kgm2": ri,
                    "rmse_definition": "over every pose time from the first"})
    return Estimate(method, model, run, out, filter=fe, selection=selection, start_note=note,
                    config=cfg, x0=x0)


def _extended_filter(inputs, *, method, model, window, clamp, names, fixed, initial,
                     sigma_pos_m, sigma_yaw_rad, tol, max_iter, opts, selection,
                     knowledge: BodyKnowledge | None = None) -> Estimate:
    if knowledge is not None and not {"mass", "izz"} <= set(names):
        held = tuple(n for n in ("mass", "izz") if n not in names)
        why = (f"known from {knowledge.source} [body]" if set(held) & set(knowledge.known)
               else "fixed")
        raise UserError(f"--method {method} estimates mass and izz; {' and '.join(held)} "
                        f"{why}: add --estimate {','.join(names + held)} (the filter starts "
                        "at the known value) or use --method ls")
    run, table = inputs()
    run = _windowed(run, as_window(window))
    if run.structure is not None:  # an undetermined Izz (no torque) is refused as for ls
        refuse_undetermined_run(run, table, names=names, fixed=fixed, clamp=clamp,
                                sigma_pos_m=sigma_pos_m, sigma_yaw_rad=sigma_yaw_rad)
    cmd_t, thrust = run.thrust_profile(table, clamp=clamp)
    q = {FILTER_STATE_NAMES[i]: v for i, v in opts.process_noise.items() if v}
    structure_guess: dict[str, float] = {}
    if run.structure is not None:
        # a structure: start from its geometry with a 100 % prior on m and Izz; the 1/m form
        # was overconfident with cx, cy estimated (18 sigma on Izz in a 60 s test run), the
        # direct form consistent
        structure_guess = {k: v for k, v in run.structure.initial_guess().items()
                           if k in names and k not in initial}
        initial = {**structure_guess, **initial}
    try:
        cfg = ExtEkfConfig(names=tuple(names), fixed=dict(fixed),
                           sigma_meas=(sigma_pos_m, sigma_pos_m, sigma_yaw_rad), q_psd=q,
                           param_form="direct" if run.structure is not None else "inverse")
    except ValueError as exc:
        raise UserError(str(exc)) from None
    from estimator.plant.model import com_from_tracked

    x0 = cfg.default_x0(None)
    for k, v in initial.items():
        if k not in cfg.labels:
            raise UserError(f"--initial {k}: not estimated by --model {model}")
        x0[cfg.labels.index(k)] = v
    # the centre of mass at the first pose (the states are the centre of mass's), then any
    # initial x, y, psi given
    b = cfg.base_params()
    cx = x0[cfg.labels.index("cx")] if "cx" in cfg.labels else b["cx"]
    cy = x0[cfg.labels.index("cy")] if "cy" in cfg.labels else b["cy"]
    x0[:3] = com_from_tracked(run.pose[0], cx, cy)
    for k in ("x", "y", "psi"):
        if k in initial:
            x0[cfg.labels.index(k)] = initial[k]
    P0 = cfg.default_P0()
    for k in ("mass", "izz"):
        if k in structure_guess:
            i = cfg.labels.index(k)
            P0[i, i] = structure_guess[k] ** 2
    priors = dict(knowledge.priors) if knowledge is not None else {}
    for k, (mean, sg) in priors.items():  # [body] priors: their mean and sigma start the filter
        i = cfg.labels.index(k)
        if k in structure_guess:  # not given with --initial
            x0[i] = mean
        P0[i, i] = sg**2
    for i, v in opts.sigma0.items():
        P0[i, i] = v**2
    ls_kwargs: dict[str, Any] = {"tol": tol, "max_iter": max_iter}
    if initial:
        ls_kwargs["initial"] = dict(initial)
    if priors:
        ls_kwargs["prior"] = knowledge.prior_vector(cfg.names)
    r, ls = estimate_ext(run.pose_t, run.pose, cmd_t, thrust, cfg, method, x0=x0, P0=P0,
                         ls_window_s=opts.ls_window_s, ls_start=opts.ls_start,
                         ls_kwargs=ls_kwargs)
    out: dict[str, Any] = {"method": method, "model": model, "run": str(run.path)}
    out.update(r.to_dict())
    final = dict(zip(cfg.labels, np.asarray(r.x[-1], float).tolist(), strict=False))
    filter_thrust_budget(out, run, table, clamp=clamp, names=names, fixed=fixed, final=final,
                         sigma_pos_m=sigma_pos_m, sigma_yaw_rad=sigma_yaw_rad)
    if ls is not None:
        out["ls"] = {"mass_kg": ls.mass_kg, "mass_sigma_kg": ls.mass_sigma_kg,
                     "izz_kgm2": ls.izz_kgm2, "izz_sigma_kgm2": ls.izz_sigma_kgm2,
                     "converged": ls.converged, "n_poses": int(len(ls.t)),
                     "ls_window_s": opts.ls_window_s, "ls_start": opts.ls_start}
    if selection is not None:
        out["model_selection"] = selection.to_dict()
    if run.structure is not None:
        # the centre of mass and Izz about the tracked origin (issue 18), as for ls
        out.update(com_keys({**cfg.base_params(), **final}, cfg.names, r.P, run))
    if knowledge is not None:
        out.update(knowledge.to_dict())
    if (truth := _truth(run)) is not None:
        tm, ti = truth
        rm, ri = r.rmse(tm, ti)
        out.update({"truth_mass_kg": tm, "truth_izz_kgm2": ti,
                    "mass_error_kg": r.mass_kg - tm, "izz_error_kgm2": r.izz_kgm2 - ti,
                    "rmse_mass_kg": rm, "rmse_izz_kgm2": ri})
    return Estimate(method, model, run, out, ext=r, ext_ls=ls, selection=selection,
                    config=cfg, x0=x0)


# --------------------------------------------------------------------------------------
# the Cramér-Rao bound of a run or a planned sequence


@dataclass
class CommandSequence:
    """A recorded run or a planned command sequence (:func:`load_sequence`)."""

    kind: str  # "recorded" or "planned"
    cmd_t: np.ndarray
    thrust_n: np.ndarray
    pose_t: np.ndarray
    s0: Any
    run: Run | None = None
    truth: dict | None = None
    thrust_sens: Any = None  # ThrustSensitivity of the rows when the table states uncertainty
    thrust_note: str = ""
    structure: Any = None  # common.structure.Structure of a structure sequence (virtual thrusts)


def _sequence_sensitivity(seq: CommandSequence, table: ThrustTable | None, duty, clamp: bool
                          ) -> CommandSequence:
    """Attach the table's thrust sensitivity (or say why there is none)."""
    from common.thrust_uncertainty import thrust_sensitivity
    from estimator.batch.consider import NO_UNCERTAINTY, THRUSTS_GIVEN

    table = table if table is not None else ThrustTable.default()
    if duty is None:
        seq.thrust_note = THRUSTS_GIVEN
    elif not table.states_uncertainty:
        seq.thrust_note = NO_UNCERTAINTY
    else:
        seq.thrust_sens = thrust_sensitivity(table, duty, clamp=clamp)
    return seq


def _structure_sensitivity(seq: CommandSequence, sens, thrusts_given: bool) -> CommandSequence:
    """Attach a structure's virtual thrust sensitivity (or say why there is none)."""
    from estimator.batch.consider import NO_UNCERTAINTY, THRUSTS_GIVEN

    if thrusts_given:
        seq.thrust_note = THRUSTS_GIVEN
    elif sens is None or sens.empty:
        seq.thrust_note = NO_UNCERTAINTY
    else:
        seq.thrust_sens = sens
    return seq


def load_sequence(path: str | Path, table: ThrustTable | None, clamp: bool = False,
                  pose_rate_hz: float = 120.0, structure: Any = None) -> CommandSequence:
    """A run folder (with poses.csv), or a folder or commands.csv holding only commands
    (poses then planned at ``pose_rate_hz``, the module starting at rest at the origin).

    ``structure`` (a :class:`common.structure.Structure` or its TOML file; a run folder's
    own structure.toml otherwise) makes it a structure sequence: virtual thrusts, 4N duty
    columns, ``table`` for the modules without their own."""
    from common.structure import Structure

    p = Path(path)
    if structure is not None and not isinstance(structure, Structure):
        structure = Structure.load(structure)
    if p.is_dir() and (p / "poses.csv").exists():
        run = read_run(p, structure=structure)
        cmd_t, thrust = run.thrust_profile(table, clamp=clamp)
        truth = run.truth
        s0 = truth.get("initial_state") if truth else None
        if s0 is None:
            s0 = [*run.pose[0], 0.0, 0.0, 0.0]
        seq = CommandSequence("recorded", cmd_t, thrust, run.pose_t, s0, run, truth,
                              structure=run.structure)
        if run.structure is not None:
            return _structure_sensitivity(seq, run.thrust_sensitivity(table, clamp=clamp),
                                          run.thrust_n is not None)
        return _sequence_sensitivity(seq, table, run.duty_pct if run.thrust_n is None else None, clamp)
    csv = p / "commands.csv" if p.is_dir() else p
    if not csv.exists():
        raise UserError(f"{p}: neither a run folder with poses.csv nor a commands.csv")
    if structure is None and p.is_dir() and (p / "structure.toml").is_file():
        structure = Structure.load(p / "structure.toml")
    if structure is not None:
        cmd_t, duty = from_commands_csv(csv, structure.n_channels)
        if len(cmd_t) < 2:
            raise UserError(f"{csv}: need at least two command rows (the last one ends the sequence)")
        s = structure.with_table(table) if table is not None else structure
        try:
            thrust = s.virtual_thrust(duty, clamp=clamp)
            sens = s.virtual_sensitivity(duty, clamp=clamp) if s.states_uncertainty else None
        except UserError as exc:
            raise UserError(f"{csv}: {exc}") from None
        seq = CommandSequence("planned", cmd_t, thrust, pose_times(cmd_t[0], cmd_t[-1], pose_rate_hz),
                              np.zeros(6), structure=s)
        return _structure_sensitivity(seq, sens, False)
    cmd_t, duty = from_commands_csv(csv)
    if len(cmd_t) < 2:
        raise UserError(f"{csv}: need at least two command rows (the last one ends the sequence)")
    if table is None:
        table = ThrustTable.default()
    try:
        thrust = table.thrust_n(duty, clamp=clamp)
    except UserError as exc:
        raise UserError(f"{csv}: {exc}") from None
    return _sequence_sensitivity(
        CommandSequence("planned", cmd_t, thrust, pose_times(cmd_t[0], cmd_t[-1], pose_rate_hz),
                        np.zeros(6)), table, duty, clamp)


@dataclass
class Bound:
    """Result of :func:`bound_sequence`: the bound, the poses it covers and the plant."""

    kind: str
    crlb: CRLBResult
    pose_t: np.ndarray
    mass_kg: float
    izz_kgm2: float
    plant_source: str
    data: dict[str, Any]

    def to_dict(self) -> dict[str, Any]:
        """The JSON object of ``tpods estimate crlb --json``."""
        return dict(self.data)


def bound_sequence(seq: CommandSequence, *, path: str = "", window: Window | str | None = None,
                   mass_kg: float | None = None, izz_kgm2: float | None = None,
                   model: str | None = None, sigma_pos_m: float = 0.01,
                   sigma_yaw_rad: float = math.radians(1.0),
                   keep_sensitivities: bool = False,
                   estimate: Sequence[str] | None = None) -> Bound:
    """Cramér-Rao bound of the model's parameters (initial state marginalised): the use
    case of ``tpods estimate crlb``.

    The plant is ``mass_kg``/``izz_kgm2`` when given, else the run's truth, else the
    paper's module; ``path`` is recorded in the result as given. A structure's bound is on
    ``estimate`` (default :data:`STRUCTURE_ESTIMATE` less its [body] known values, as
    :func:`body_knowledge`), its [body] priors' information added to the Fisher matrix.
    """
    if estimate is not None and seq.structure is None:
        raise UserError("--estimate: the bound of a single-module run follows --model")
    t0, t1 = as_window(window)
    s0 = seq.s0
    if seq.kind == "recorded":
        run = seq.run.window(t0, t1) if (t0, t1) != (None, None) else seq.run
        pose_t = run.pose_t
        if run.pose_t[0] != seq.run.pose_t[0]:
            s0 = [*run.pose[0], 0.0, 0.0, 0.0]
    else:
        pose_t = seq.pose_t
        keep = np.ones(len(pose_t), bool)
        if t0 is not None:
            keep &= pose_t >= t0
        if t1 is not None:
            keep &= pose_t <= t1
        if keep.sum() < 3:
            raise UserError(f"window {window} holds fewer than 3 planned poses")
        pose_t = pose_t[keep]
    truth = seq.truth or {}
    body = seq.structure.body if seq.structure is not None else None
    mass = mass_kg or truth.get("mass_kg") or (body and body.mass_kg) or PAPER_MASS_KG
    izz = izz_kgm2 or truth.get("izz_kgm2") or (body and body.izz_kgm2) or PAPER_IZZ_KGM2
    source = "command line" if (mass_kg or izz_kgm2) else ("run truth" if truth else
                                                           "structure [body]" if body and body.mass_kg
                                                           else "paper nominal")
    params = {"mass": float(mass), "izz": float(izz), "arm": float(truth.get("arm_m", 0.05)),
              **{k: float(truth.get(k, 0.0)) for k in ("ct", "cr", "kb", "ax", "ay")}}
    names = MODELS[model or DEFAULT_MODEL]
    if seq.structure is not None:
        com = (truth["cx"], truth["cy"]) if "cx" in truth else ((body and body.com_m) or (0.0, 0.0))
        params.update(cx=float(com[0]), cy=float(com[1]))
        knowledge = body_knowledge(seq.structure, estimate, {})
        names = knowledge.names
        if model not in (None, DEFAULT_MODEL):  # friction/tilt: the model's parameters too
            names, _ = with_model(model, names)
    model = model or DEFAULT_MODEL
    try:
        with np.errstate(all="ignore"):
            c = crlb(pose_t, seq.cmd_t, seq.thrust_n, params, s0=s0, sigma_pos_m=sigma_pos_m,
                     sigma_yaw_rad=sigma_yaw_rad, keep_sensitivities=keep_sensitivities,
                     names=names)
        if not np.all(np.isfinite(c.fisher)):
            raise np.linalg.LinAlgError
    except (np.linalg.LinAlgError, OverflowError, FloatingPointError, ValueError):
        raise UserError(f"the bound cannot be computed: the predicted motion of a {mass:g} kg, "
                        f"Izz {izz:g} kg m^2 body under these thrusts is not finite (check --mass "
                        "and --izz, and the thrust table's unit)") from None
    if seq.structure is not None and knowledge.priors:
        c = _with_prior_information(c, knowledge.priors)
    out: dict[str, Any] = {
        "sequence": seq.kind, "path": str(path), "n_poses": c.n_poses,
        "duration_s": float(pose_t[-1] - pose_t[0]), "mass_kg": mass, "izz_kgm2": izz,
        "plant_source": source,
        "crlb_mass_sigma_kg": c.mass_sigma_kg, "crlb_izz_sigma_kgm2": c.izz_sigma_kgm2,
        "crlb_mass_rel": c.mass_sigma_kg / mass, "crlb_izz_rel": c.izz_sigma_kgm2 / izz,
        "crlb_corr_mass_izz": _corr(c, "mass", "izz"),
        "logdet_info": c.logdet, "sigma_pos_m": sigma_pos_m, "sigma_yaw_rad": sigma_yaw_rad,
        "model": model, "estimated": list(c.names)}
    if seq.structure is not None:
        for k, n in (("crlb_mass_sigma_kg", "mass"), ("crlb_izz_sigma_kgm2", "izz"),
                     ("crlb_mass_rel", "mass"), ("crlb_izz_rel", "izz")):
            if n not in c.names:
                out[k] = 0.0  # known: fixed at its value
        out.update(knowledge.to_dict())
    for n, s in zip(c.names, c.sigma, strict=True):
        if n not in ("mass", "izz"):
            out[f"crlb_{n}_sigma"] = float(s)
    sd = np.where(c.sigma > 0, c.sigma, 1.0)
    out["crlb_correlation"] = (c.cov / np.outer(sd, sd)).tolist()
    out.update(_bound_budget(seq, c, pose_t, params, s0, sigma_pos_m, sigma_yaw_rad))
    return Bound(seq.kind, c, pose_t, mass, izz, source, out)


def _corr(c: CRLBResult, a: str, b: str) -> float | None:
    """The bound's correlation of ``a`` and ``b`` (None when either is not estimated)."""
    if a not in c.names or b not in c.names:
        return None
    i, j = c.names.index(a), c.names.index(b)
    return float(c.cov[i, j] / (c.sigma[i] * c.sigma[j]))


def _with_prior_information(c: CRLBResult, priors: Mapping[str, tuple[float, float]]
                            ) -> CRLBResult:
    """The bound with Gaussian priors ``name -> (mean, sigma)`` on its parameters: their
    information ``1/sigma^2`` added to the Fisher matrix (the Bayesian bound of a linear
    Gaussian problem)."""
    F = np.array(c.fisher, float)
    for j, n in enumerate(c.names):
        if n in priors:
            F[6 + j, 6 + j] += priors[n][1] ** -2
    M, cov, sig, logdet = crlb_from_fisher(F, c.names)
    return replace(c, fisher=F, marginal_info=M, cov=cov, sigma=sig, logdet=logdet)


def _bound_budget(seq: CommandSequence, c: CRLBResult, pose_t, params, s0, sigma_pos_m,
                  sigma_yaw_rad) -> dict[str, Any]:
    """The total uncertainty beside the noise bound: the thrust table's consider part at the
    bound's plant (``*_sigma_thrust``, ``*_sigma_total``; total = RSS of the two)."""
    out: dict[str, Any] = {"thrust_uncertainty": {"included": seq.thrust_sens is not None,
                                                  "note": seq.thrust_note}}
    if seq.thrust_sens is None:
        return out
    from estimator.batch.consider import bound_consider

    s0 = np.zeros(6) if s0 is None else np.asarray(s0, float)
    cons = bound_consider(pose_t, seq.cmd_t, seq.thrust_sens, params, s0, c.names,
                          sigma_pos_m=sigma_pos_m, sigma_yaw_rad=sigma_yaw_rad)
    st = np.sqrt(np.maximum(np.diag(cons.cov_thrust)[6:], 0.0))
    total = np.hypot(c.sigma, st)
    out["thrust_uncertainty"]["terms"] = list(cons.names)
    for j, n in enumerate(c.names):
        key = {"mass": "mass_sigma_{}_kg", "izz": "izz_sigma_{}_kgm2"}.get(n, n + "_sigma_{}")
        out[key.format("thrust")] = float(st[j])
        out[key.format("total")] = float(total[j])
    return out
