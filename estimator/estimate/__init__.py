"""The estimator's use cases, one function each: what ``tpods estimate batch`` and
``tpods estimate crlb``, the demo, the reports and notebooks call.

- :func:`estimate_run` estimates mass and Izz (and, by model, friction, yaw bias, tilt)
  of a run by batch least squares (``ls``), the EKF (``ekf``) or the LS-started EKF
  (``ls-ekf``), under a named model or the one a likelihood-ratio test picks
  (``model="auto"``). Its settings are an :class:`EstimateOptions` or the same names as
  keywords. Returns an :class:`Estimate`; ``to_dict()`` is the JSON object
  ``tpods estimate batch --json`` prints.
- :func:`bound_sequence` is the Cramér-Rao bound of a recorded run or of a planned
  command sequence (:func:`load_sequence`), settings a :class:`BoundOptions` or keywords.
  Returns a :class:`Bound`.
- :func:`filter_config` builds the EKF setting from a preset and :class:`FilterOptions`
  (the filter options of ``estimate batch``, ``estimate live`` and ``estimate montecarlo``).

The functions print nothing and write no file: the command-line modules
(``tpods/cli/estimate*.py``) parse arguments, read inputs, call them and print or write
the results. Errors a user can fix raise :class:`common.errors.UserError` (their text
names the command-line options, as the CLI shows it).

The modules (this file only re-exports them): ``options`` (the settings), ``result``
(:class:`Estimate`), ``knowledge`` (a structure's [body] knowledge), ``structure_run``
(structure-run helpers and JSON keys), ``dispatch`` (:func:`estimate_run`), ``batch_fit``
(its least-squares path), ``filter_fit`` (its filter paths and their thrust budget),
``sequence`` (what a bound covers) and ``bound`` (:func:`bound_sequence`).
"""

from estimator.estimate.batch_fit import _least_squares
from estimator.estimate.bound import (
    Bound,
    _bound_budget,
    _corr,
    _with_prior_information,
    bound_sequence,
)
from estimator.estimate.dispatch import _select_structure_model, _start_at, estimate_run
from estimator.estimate.filter_fit import (
    _extended_filter,
    _ideal_filter,
    _truth,
    filter_thrust_budget,
)
from estimator.estimate.knowledge import BodyKnowledge, body_knowledge
from estimator.estimate.options import (
    METHODS,
    STRUCTURE_ESTIMATE,
    BoundOptions,
    EstimateOptions,
    FilterOptions,
    Inputs,
    Window,
    _windowed,
    as_window,
    filter_config,
    with_overrides,
)
from estimator.estimate.result import Estimate
from estimator.estimate.sequence import (
    CommandSequence,
    _sequence_sensitivity,
    _structure_sensitivity,
    load_sequence,
)
from estimator.estimate.structure_run import (
    _is_structure_run,
    _structure_consider,
    _structure_of,
    _with_structure,
    com_keys,
    structure_keys,
)

__all__ = [
    "METHODS", "STRUCTURE_ESTIMATE", "Window", "Inputs",
    "EstimateOptions", "BoundOptions", "FilterOptions", "filter_config", "with_overrides",
    "as_window", "Estimate", "BodyKnowledge", "body_knowledge", "structure_keys", "com_keys",
    "estimate_run", "filter_thrust_budget", "CommandSequence", "load_sequence", "Bound",
    "bound_sequence",
    # private names of the former single module, re-exported for code that imported them
    "_windowed", "_truth", "_start_at", "_select_structure_model", "_is_structure_run",
    "_structure_of", "_with_structure", "_structure_consider", "_least_squares",
    "_ideal_filter", "_extended_filter", "_sequence_sensitivity", "_structure_sensitivity",
    "_corr", "_with_prior_information", "_bound_budget",
]
