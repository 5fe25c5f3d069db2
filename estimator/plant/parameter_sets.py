"""Model options of the estimators: which plant parameters are estimated jointly.

=================  =========================================  ===========================
option             estimated parameters (``names``)            held fixed
=================  =========================================  ===========================
``ideal``          mass, izz                                   ct = cr = kb = ax = ay = 0
``friction``       mass, izz, ct, cr, kb                       ax = ay = 0
``friction+tilt``  mass, izz, ct, cr, kb, ax, ay               --
``auto``           chosen from the three by                    --
                   :func:`estimator.batch.model_select.select_model`
=================  =========================================  ===========================

Units (SI): ct N s/m (viscous translational friction), cr N m s/rad (rotational
friction), kb N m s/m (yaw torque ``kb*sqrt(u^2+v^2)`` induced by translation), ax, ay
m/s^2 (constant lab-frame acceleration of a table that is not level: ``g*tilt``; a
0.1 mrad tilt gives about 1e-3 m/s^2). The plant itself is :mod:`estimator.plant.model`.

Pure data and mapping helpers; the CLI hooks live in :mod:`tpods.cli.estimate_realism`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from common.errors import UserError

MODELS: dict[str, tuple[str, ...]] = {
    "ideal": ("mass", "izz"),
    "friction": ("mass", "izz", "ct", "cr", "kb"),
    "friction+tilt": ("mass", "izz", "ct", "cr", "kb", "ax", "ay"),
}
"""Nested model options, smallest first, and the parameters each one estimates."""

MODEL_CHOICES = (*MODELS, "auto")
"""Values of ``--model`` (``auto`` selects one of MODELS from the data)."""

DEFAULT_MODEL = "ideal"

EXTRA_PARAMS = ("ct", "cr", "kb", "ax", "ay")
"""Parameters beyond mass and Izz (their initial guess is 0: no friction, level table)."""

PARAM_UNITS = {"mass": "kg", "izz": "kg m^2", "ct": "N s/m", "cr": "N m s/rad",
               "kb": "N m s/m", "ax": "m/s^2", "ay": "m/s^2", "cx": "m", "cy": "m"}


def names_for(model: str) -> tuple[str, ...]:
    """Estimated parameters of a model option (``ideal``, ``friction``, ``friction+tilt``)."""
    try:
        return MODELS[model]
    except KeyError:
        raise UserError(f"unknown model {model!r}; choose from {', '.join(MODELS)}") from None


def model_of(names: Sequence[str]) -> str | None:
    """The model option whose parameters are exactly ``names`` (any order), else None."""
    s = set(names)
    for k, v in MODELS.items():
        if set(v) == s:
            return k
    return None


def fixed_for(model: str, fixed: Mapping[str, float] | None = None) -> dict[str, float]:
    """The fixed values a model implies: its non-estimated extras at 0, overridden by ``fixed``.

    Raises UserError when ``fixed`` sets a parameter the model estimates.
    """
    names = names_for(model)
    fixed = dict(fixed or {})
    clash = sorted(set(fixed) & set(names))
    if clash:
        raise UserError(f"--model {model} estimates {', '.join(clash)}; do not also fix "
                        f"{'it' if len(clash) == 1 else 'them'} (use --initial for a start value)")
    out = {k: 0.0 for k in EXTRA_PARAMS if k not in names}
    out.update(fixed)
    return out


def with_model(model: str, names: Sequence[str], fixed: Mapping[str, float] | None = None
               ) -> tuple[tuple[str, ...], dict[str, float]]:
    """``names`` (e.g. a structure's mass, izz, cx, cy) plus the parameters ``model`` adds
    (``friction``: ct, cr, kb; ``friction+tilt``: also ax, ay), and the fixed values with the
    model's other extras at 0 (:func:`fixed_for`; UserError when ``fixed`` sets one it
    estimates)."""
    extra = tuple(n for n in names_for(model) if n not in names)
    fx = fixed_for(model, {k: v for k, v in (fixed or {}).items() if k not in names})
    return tuple(names) + extra, fx


def resolve_names(model: str | None, estimate: Sequence[str] | None,
                  default_estimate: Sequence[str] = ("mass", "izz")) -> tuple[str, ...]:
    """Estimated names from ``--model`` and ``--estimate`` (they must agree when both are given).

    ``model`` None or ``ideal`` with a non-default ``estimate`` keeps the explicit list
    (the batch estimator's ``--estimate`` predates the model options).
    """
    estimate = tuple(estimate) if estimate is not None else tuple(default_estimate)
    if model is None or model == "auto":
        return estimate
    names = names_for(model)
    if set(estimate) in (set(default_estimate), set(names)):
        return names
    if model == DEFAULT_MODEL:
        return estimate
    raise UserError(f"--model {model} estimates {','.join(names)}; it conflicts with --estimate "
                    f"{','.join(estimate)} (give one of them)")
