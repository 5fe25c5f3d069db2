"""Extended Kalman filter on the augmented state ``z = (x, y, psi, u, v, r, m, Izz)``: the
one import of the filter (every name of it is importable from here).

Two implementations of one filter:

- plain array functions (:func:`propagate`, :func:`ekf_predict`, :func:`ekf_update`,
  :func:`run_ekf`): the lean path used for live estimation and the ``estimate batch
  --method ekf|ls-ekf`` command (tens of thousands of pose updates per second);
- :class:`TpodsEKF`, a filterpy ``ExtendedKalmanFilter`` whose ``predict_x`` runs the
  same nonlinear propagation and sets ``F`` to the analytic transition matrix, with an
  angle-wrapping residual and filterpy's Joseph-form update (:func:`run_filterpy`): the
  public, tested adapter and the tests' reference, in
  :mod:`estimator.filters.filterpy_adapter` (loaded from here on first use, so that the
  lean path does not load filterpy and scipy; the adapter imports the modules below, never
  this one).

Each part has its module; this one re-exports them:

- :mod:`estimator.filters.config`: the state layout, :class:`EkfConfig`, :data:`PAPER`,
  :data:`PRESETS`, :func:`parse_state_values`;
- :mod:`estimator.filters.kernels`: propagation, predict and update on plain arrays
  (underweighting, the 1/m form :func:`inverse_correction`, the off-centre pose update) and
  the filter's conventions;
- :mod:`estimator.filters.result`: :class:`EkfResult` (:class:`FilterHistory`) and its
  divergence and consistency tests;
- :mod:`estimator.filters.loop`: :func:`make_schedule`, :func:`run_filter` (the loop for
  any parameter set, the extended filter of :mod:`estimator.filters.ext` too),
  :func:`run_ekf`;
- :mod:`estimator.filters.plausibility`: what a run says about itself;
- :mod:`estimator.filters.methods`: ``ekf`` and ``ls-ekf`` on a whole run
  (:func:`estimate_filter`, :class:`FilterEstimate`), :func:`initial_rates`.

A re-export is a second name for the same object: to monkeypatch a function, patch it in
the module that defines it (e.g. ``estimator.filters.loop.run_filter``), where its
callers look it up.
"""

from __future__ import annotations

from estimator.filters.config import (
    INV_IDX,
    NX,
    NZ,
    PAPER,
    PARAM_FORMS,
    PRESETS,
    STATE_NAMES,
    STATE_UNITS,
    EkfConfig,
    parse_state_values,
)
from estimator.filters.config import _known_plant as _known_plant
from estimator.filters.kernels import _JAC_POS as _JAC_POS
from estimator.filters.kernels import (
    MIN_INV_RATIO,
    TWO_PI,
    ekf_predict,
    ekf_update,
    filter_plant,
    inverse_correction,
    propagate,
    uw_ratio,
    wrap_residual,
)
from estimator.filters.kernels import _dot as _dot
from estimator.filters.kernels import _eye as _eye
from estimator.filters.kernels import _h as _h
from estimator.filters.kernels import _inv_sym3 as _inv_sym3
from estimator.filters.kernels import _max_eig_sym3 as _max_eig_sym3
from estimator.filters.kernels import _offset_spec as _offset_spec
from estimator.filters.kernels import _predict as _predict
from estimator.filters.kernels import _rhs_jac as _rhs_jac
from estimator.filters.kernels import _update as _update
from estimator.filters.kernels import _update_offset as _update_offset
from estimator.filters.loop import (
    Schedule,
    initial_estimate,
    make_schedule,
    run_ekf,
    run_filter,
)
from estimator.filters.methods import (
    FILTER_METHODS,
    LS_STARTS,
    FilterEstimate,
    estimate_filter,
    initial_rates,
)
from estimator.filters.methods import _checked as _checked
from estimator.filters.plausibility import (
    INFO_FRACTION,
    filter_plausibility,
    pose_scatter,
    residual_rms,
)
from estimator.filters.result import NIS_BLOCK, EkfResult, FilterHistory

__all__ = [
    "FILTER_METHODS", "INFO_FRACTION", "INV_IDX", "LS_STARTS", "MIN_INV_RATIO", "NIS_BLOCK", "NX",
    "NZ", "PAPER", "PARAM_FORMS", "PRESETS", "STATE_NAMES", "STATE_UNITS", "TWO_PI", "EkfConfig",
    "EkfResult", "FilterEstimate", "FilterHistory", "Schedule", "ekf_predict", "ekf_update",
    "estimate_filter", "filter_plant", "filter_plausibility", "initial_estimate",
    "initial_rates", "inverse_correction", "make_schedule", "parse_state_values",
    "pose_scatter", "propagate", "residual_rms", "run_ekf", "run_filter", "uw_ratio",
    "wrap_residual",
]
"""(``TpodsEKF`` and ``run_filterpy`` are importable too, loaded on first use.)"""


def __getattr__(name: str):
    """``TpodsEKF`` and ``run_filterpy`` from :mod:`estimator.filters.filterpy_adapter`."""
    if name in ("TpodsEKF", "run_filterpy"):
        # lazy: filterpy imports scipy (~0.6 s), which neither the lean filter nor `tpods --help` needs
        from estimator.filters import filterpy_adapter

        return getattr(filterpy_adapter, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
