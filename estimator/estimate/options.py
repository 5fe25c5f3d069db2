"""The settings of the estimate use cases: :class:`EstimateOptions` (``tpods estimate
batch``), :class:`BoundOptions` (``tpods estimate crlb``), :class:`FilterOptions` and the
EKF setting made of them (:func:`filter_config`), and the analysis window.

The option classes only store settings (as scikit-learn's estimators do): the use cases
check them, so a bad value raises :class:`common.errors.UserError` with the text of the
command-line option when it is used, before any run is read.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from typing import Any, TypeVar

from common.errors import UserError
from common.runfolder import Run
from common.thrust_table import ThrustTable
from estimator.batch.least_squares import parse_window
from estimator.filters.ekf import PRESETS, EkfConfig

METHODS = ("ls", "ekf", "ls-ekf")
STRUCTURE_ESTIMATE = ("mass", "izz", "cx", "cy")
"""Default unknowns of a structure run: mass, Izz about the centre of mass and
the centre of mass (cx, cy) in the tracked frame (m)."""
Window = tuple[float | None, float | None]
Inputs = Callable[[], tuple[Run, ThrustTable]]
"""The run and the thrust table of an estimate, read when first called (after the option
checks)."""


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




@dataclass(frozen=True)
class EstimateOptions:
    """The settings of :func:`estimator.estimate.estimate_run` (``tpods estimate batch``).

    ``method`` ``ls``, ``ekf`` or ``ls-ekf``; ``model`` ``ideal``, ``friction``,
    ``friction+tilt``, ``auto`` or None (the parameters ``estimate`` with ``fixed``);
    ``window`` ``(t0, t1)`` or ``"T0:T1"``; ``clamp`` clamps duties into the thrust table's
    range; ``initial`` the initial guess by name; ``sigma_pos_m``, ``sigma_yaw_rad`` the
    measurement noise; ``tol``, ``max_iter`` the batch fit's threshold and iteration cap;
    ``select_alpha`` the level of ``model="auto"``; ``filter_options`` the filters' setting
    (None: the paper's preset); ``structure`` a :class:`common.structure.Structure` or its
    TOML file. :func:`estimator.estimate.estimate_run` documents each in full.
    """

    method: str = "ls"
    model: str | None = None
    window: Window | str | None = None
    clamp: bool = False
    estimate: Sequence[str] | None = ("mass", "izz")
    fixed: Mapping[str, float] | None = None
    initial: Mapping[str, float] | None = None
    sigma_pos_m: float = 0.01
    sigma_yaw_rad: float = math.radians(1.0)
    tol: float = 1e-8
    max_iter: int = 50
    select_alpha: float = 1e-3
    filter_options: FilterOptions | None = None
    structure: Any = None


@dataclass(frozen=True)
class BoundOptions:
    """The settings of :func:`estimator.estimate.bound_sequence` (``tpods estimate crlb``).

    ``window`` ``(t0, t1)`` or ``"T0:T1"``; ``mass_kg``, ``izz_kgm2`` the plant (None: the
    run's truth, a structure's [body], else the paper's module); ``model`` the parameter set
    (None: ideal); ``sigma_pos_m``, ``sigma_yaw_rad`` the measurement noise;
    ``keep_sensitivities`` keeps the output sensitivities in the result (for plots);
    ``estimate`` a structure's unknowns (None: from its [body]).
    """

    window: Window | str | None = None
    mass_kg: float | None = None
    izz_kgm2: float | None = None
    model: str | None = None
    sigma_pos_m: float = 0.01
    sigma_yaw_rad: float = math.radians(1.0)
    keep_sensitivities: bool = False
    estimate: Sequence[str] | None = None


Options = TypeVar("Options", EstimateOptions, BoundOptions)


def with_overrides(options: Options | None, cls: type[Options], overrides: Mapping[str, Any],
                   caller: str) -> Options:
    """``options`` (default ``cls()``) with the fields ``overrides`` names replaced: the
    keyword arguments of a use case. An unknown keyword raises TypeError naming it, as
    Python does for a function's unknown keyword argument."""
    base = cls() if options is None else options
    if not isinstance(base, cls):
        raise TypeError(f"{caller}() options must be {cls.__name__}, not {type(options).__name__}")
    known = {f.name for f in fields(cls)}
    for k in overrides:
        if k not in known:
            raise TypeError(f"{caller}() got an unexpected keyword argument {k!r}")
    return replace(base, **overrides) if overrides else base


def as_window(window: Window | str | None) -> Window:
    """``None``, ``"T0:T1"`` or ``(t0, t1)`` -> ``(t0, t1)`` (raises UserError when bad)."""
    if window is None or isinstance(window, str):
        return parse_window(window)
    t0, t1 = window
    if t0 is not None and t1 is not None and t1 <= t0:
        raise UserError(f"window end must follow its start, got {t0}:{t1}")
    return t0, t1


def _windowed(run: Run, window: Window) -> Run:
    """``run`` cut to ``window`` (an :func:`as_window` value)."""
    return run.window(*window) if window != (None, None) else run
