"""The use case of ``tpods estimate batch``: :func:`estimate_run` checks the options,
resolves the model and the unknowns (``--model auto`` by likelihood-ratio tests, a
structure's [body] knowledge, a staged start for the larger models) and hands the run to
the batch least-squares path (:mod:`estimator.estimate.batch_fit`) or a filter path
(:mod:`estimator.estimate.filter_fit`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from common.errors import UserError
from common.runfolder import Run, read_run
from common.thrust_table import ThrustTable, load_thrust_table
from estimator.batch.input_params import is_input_name, split_names
from estimator.batch.model_select import ModelFit, fit_models, select_model
from estimator.estimate.batch_fit import _least_squares
from estimator.estimate.filter_fit import _extended_filter, _ideal_filter
from estimator.estimate.knowledge import body_knowledge
from estimator.estimate.options import (
    METHODS,
    EstimateOptions,
    FilterOptions,
    _windowed,
    as_window,
    with_overrides,
)
from estimator.estimate.result import Estimate
from estimator.estimate.structure_run import _is_structure_run, _structure_of, _with_structure
from estimator.estimate.vehicle_start import vehicle_scan
from estimator.plant.model import STATE_NAMES
from estimator.plant.parameter_sets import (
    DEFAULT_MODEL,
    MODELS,
    fixed_for,
    model_of,
    resolve_names,
    with_model,
)


def _start_at(fit: ModelFit, initial: dict[str, float], note: str | None
              ) -> tuple[dict[str, float], str | None]:
    """Start the batch fit at a staged fit's optimum (when it converged)."""
    r = fit.result
    if r.converged and np.all(np.isfinite(r.z0)):
        return (dict(zip(STATE_NAMES + tuple(r.names), r.z0.tolist(), strict=True)),
                f"started at the staged fit's optimum ({fit.start})")
    return initial, note


def _select_structure_model(inputs: tuple[Run, ThrustTable], *, window, clamp, names, fixed,
                            initial, alpha, sigma_pos_m, sigma_yaw_rad, log):
    """``--model auto`` on a structure: the nested models (ideal, friction, friction+tilt)
    each with the structure's other unknowns (cx, cy), fitted from the structure's start
    and chosen by likelihood-ratio tests (:func:`select_model`). Returns the selection, the
    chosen model, its names and fixed values, and the start at its optimum."""
    run, table = inputs
    wrun = _windowed(run, as_window(window))
    cmd_t, thrust = wrun.thrust_profile(table, clamp=clamp)
    extra = tuple(n for n in names if n not in ("mass", "izz"))
    # the candidates start where the final fit would: a vehicle's scan, else its geometry
    scanned = vehicle_scan(wrun, table, names, fixed, initial, clamp=clamp,
                           sigma_pos_m=sigma_pos_m, sigma_yaw_rad=sigma_yaw_rad)
    start = {**{k: v for k, v in run.structure.initial_guess().items() if k in names},
             **(scanned[0] if scanned else initial)}
    selection = select_model(wrun.pose_t, wrun.pose, cmd_t, thrust, alpha=alpha,
                             fixed={k: v for k, v in fixed.items() if k not in names},
                             initial=start, extra_names=extra, sigma_pos_m=sigma_pos_m,
                             sigma_yaw_rad=sigma_yaw_rad, warm=scanned is not None,
                             start_label=scanned[1] if scanned else "the structure's start")
    chosen = selection.chosen
    if log is not None:
        log(f"model selection on {wrun.path} (--model auto, with {', '.join(extra)} in every "
            "model):")
        for line in selection.table_lines():
            log(line)
    names, fixed = with_model(chosen, names, fixed)
    # the final fit starts where its candidate ended (converged) or began (the scan: not
    # scanned again for the chosen model's names)
    initial, note = _start_at(selection.fits[chosen], dict(scanned[0] if scanned else initial),
                              scanned[1] if scanned else None)
    return selection, chosen, names, fixed, initial, note


def estimate_run(run: Run | str | Path, table: ThrustTable | str | Path | None = None,
                 options: EstimateOptions | None = None, *,
                 log: Callable[[str], None] | None = None, **overrides: Any) -> Estimate:
    """Estimate a run's parameters: the use case of ``tpods estimate batch``.

    The settings are ``options`` (an :class:`EstimateOptions`, default every default) with
    ``overrides`` replacing its fields by name (``estimate_run(d, method="ekf")``); an
    unknown keyword raises TypeError.

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
    o = with_overrides(options, EstimateOptions, overrides, "estimate_run")
    if o.estimate is not None and any(is_input_name(n) for n in o.estimate):
        # a vehicle's valve delay / supply drop estimated with the body
        from estimator.estimate.vehicle_inputs import estimate_with_inputs

        return estimate_with_inputs(run, table, o, *split_names(o.estimate), log=log)
    method, model, window, clamp, estimate = o.method, o.model, o.window, o.clamp, o.estimate
    fixed, initial, select_alpha, structure = o.fixed, o.initial, o.select_alpha, o.structure
    sigma_pos_m, sigma_yaw_rad, max_iter = o.sigma_pos_m, o.sigma_yaw_rad, o.max_iter
    filter_options = o.filter_options
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

    def resolved() -> EstimateOptions:
        """The options as resolved so far: the model used, the names to estimate, the fixed
        and initial values (dicts) and the filter options (what the paths take)."""
        return replace(o, model=model, estimate=names, fixed=fixed, initial=initial,
                       filter_options=opts)

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
            # the candidates start where the final fit would: the caller's start, if any
            selection = select_model(wrun.pose_t, wrun.pose, cmd_t, thrust, alpha=select_alpha,
                                     fixed=dict(fixed), sigma_pos_m=sigma_pos_m,
                                     sigma_yaw_rad=sigma_yaw_rad, initial=dict(initial),
                                     start_label="the caller's start (--initial)" if initial
                                     else "default start")
            model = selection.chosen
            if log is not None:
                log(f"model selection on {wrun.path} (--model auto):")
                for line in selection.table_lines():
                    log(line)
            initial, note = _start_at(selection.fits[model], initial, note)
        names = resolve_names(model, names)
        fixed = fixed_for(model, fixed)
        if method != "ls" and model != DEFAULT_MODEL:
            return _extended_filter(inputs, resolved(), selection=selection)
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
    if method != "ls" and is_structure:  # the extended filter carries cx, cy
        return _extended_filter(inputs, resolved(), selection=selection, knowledge=knowledge)
    if method != "ls":
        return _ideal_filter(inputs, resolved(), selection=selection, note=note, log=log)
    return _least_squares(inputs, resolved(), selection=selection, note=note, log=log,
                          knowledge=knowledge)
