"""The use case of ``tpods estimate crlb``: :func:`crlb_report` bounds the parameters of a
recorded run or of a planned command sequence (a folder or commands.csv holding only
commands, poses planned at ``pose_rate_hz``) and returns a :class:`BoundReport`: the
JSON object, the warnings, the console ``lines()`` and ``write(main, folder)`` of crlb.json
(and, in a folder, sensitivities.png: the pose sensitivities to mass and Izz).

With delay or drop among ``estimate`` the bound is the joint one of a vehicle's body and
valve parameters (:func:`estimator.estimate.vehicle_bound.bound_with_inputs`) at ``at``
(mass kg, izz kg m^2, cx/cy m, delay s, drop per other open valve). The size of the work
is checked before anything is allocated (:mod:`estimator.plant.size_checks`). Nothing is
printed; a user's error raises :class:`common.errors.UserError`.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any


@dataclass
class BoundReport:
    """A bound as ``estimate crlb`` reports it. ``bound`` is the
    :class:`estimator.estimate.Bound`, ``out`` its JSON object, ``run_dir`` as given;
    ``joint`` the joint bound with the valves; ``warnings`` (text, no prefix) are always
    said, ``text_warnings`` only beside the text report."""

    bound: Any
    out: dict[str, Any]
    run_dir: str
    joint: bool = False
    warnings: list[str] = field(default_factory=list)
    text_warnings: list[str] = field(default_factory=list)

    def json_text(self) -> str:
        """The ``--json`` line (numpy values as numbers)."""
        from common.runwriter import json_default

        return json.dumps(self.out, default=json_default)

    def lines(self) -> list[str]:
        from estimator.reports.estimate_text import crlb_lines, inputs_bound_lines

        if self.joint:
            return inputs_bound_lines(self.out, self.run_dir, self.bound.plant_source)
        return crlb_lines(self.bound, self.out, self.run_dir)

    def write(self, main: Path, folder: Path | None) -> None:
        """crlb.json to ``main``; with a ``folder`` (else None) sensitivities.png."""
        if self.joint:
            main.write_text(json.dumps(self.out, indent=2, default=str) + "\n")
            return
        main.write_text(json.dumps(self.out, indent=2) + "\n")
        if folder is not None:
            from estimator.reports.plots.batch import plot_sensitivities

            b = self.bound
            c = b.crlb
            plot_sensitivities(b.pose_t, c.sens_x[:, :, :2], c.names[:2],
                               [{"mass": b.mass_kg, "izz": b.izz_kgm2}.get(n, 1.0) for n in c.names[:2]],
                               folder / "sensitivities.png",
                               title=f"Sensitivities of {Path(self.run_dir).name}")

    @property
    def folder_files(self) -> str:
        return "" if self.joint else " and sensitivities.png"


def crlb_report(run_dir: str | Path, thrust_table: str | Path | None = None, *,
                clamp: bool = False, pose_rate_hz: float = 120.0, structure: Any = None,
                window: str | tuple | None = None, mass_kg: float | None = None,
                izz_kgm2: float | None = None, model: str | None = None,
                sigma_pos_m: float = 0.01, sigma_yaw_rad: float = math.radians(1.0),
                estimate: Sequence[str] | None = None, at: Mapping[str, float] | None = None,
                keep_sensitivities: bool = False) -> BoundReport:
    """The Cramér-Rao bound of ``run_dir`` (see the module's docstring); ``mass_kg``,
    ``izz_kgm2`` the plant (default the run's truth, else the paper's module), ``model``
    the parameter set, ``keep_sensitivities`` for the figure."""
    from common.errors import UserError

    if estimate and any(n in ("delay", "drop") or n.startswith("drop.") for n in estimate):
        return _joint(run_dir, thrust_table, structure, window, mass_kg, izz_kgm2, model,
                      sigma_pos_m, sigma_yaw_rad, estimate, at)
    if at:
        raise UserError("--at sets the point of a vehicle's joint bound: name delay or drop "
                        "in --estimate (else --mass and --izz)")
    from common.thrust_table import load_thrust_table
    from estimator.estimate import bound_sequence, load_sequence
    from estimator.plant.parameter_sets import DEFAULT_MODEL, MODELS
    from estimator.plant.size_checks import check_crlb_size, check_planned_crlb_size

    n_params = len(MODELS[model or DEFAULT_MODEL])
    table = load_thrust_table(thrust_table)
    check_planned_crlb_size(run_dir, pose_rate_hz, n_params)  # before the poses are allocated
    seq = load_sequence(run_dir, table, clamp, pose_rate_hz, structure=structure)
    if seq.structure is not None and thrust_table:
        seq.structure.check_table_option()
    check_crlb_size(run_dir, seq.pose_t, len(seq.cmd_t), n_params)
    b = bound_sequence(seq, path=str(run_dir), window=window, mass_kg=mass_kg, izz_kgm2=izz_kgm2,
                       model=model, sigma_pos_m=sigma_pos_m, sigma_yaw_rad=sigma_yaw_rad,
                       keep_sensitivities=keep_sensitivities, estimate=estimate)
    out = b.to_dict()
    rep = BoundReport(b, out, str(run_dir))
    if not out["thrust_uncertainty"]["included"]:
        rep.text_warnings.append(out["thrust_uncertainty"]["note"])
    return rep


def _joint(run_dir, thrust_table, structure, window, mass_kg, izz_kgm2, model, sigma_pos_m,
           sigma_yaw_rad, estimate, at) -> BoundReport:
    """The joint bound of ``estimate`` (plant names and delay/drop) on a recorded vehicle
    run; a not-informed parameter is a warning and ``null`` in the JSON's ``crlb_sigma``
    with its reason in ``not_informed``."""
    from common.errors import UserError
    from estimator.batch.input_params import split_names
    from estimator.estimate import BoundOptions
    from estimator.estimate.vehicle_bound import bound_with_inputs

    if model not in (None, "ideal"):
        raise UserError("--estimate with delay/drop bounds the ideal model's parameters (name "
                        "friction ones in --estimate instead of --model)")
    o = BoundOptions(window=window, mass_kg=mass_kg, izz_kgm2=izz_kgm2, sigma_pos_m=sigma_pos_m,
                     sigma_yaw_rad=sigma_yaw_rad)
    b = bound_with_inputs(run_dir, thrust_table, o, *split_names(estimate), structure=structure,
                          at=at)
    out = b.to_dict()
    rep = BoundReport(b, out, str(run_dir), joint=True, warnings=list(out["warnings"]))
    if not out["thrust_uncertainty"]["included"]:
        rep.warnings.append(out["thrust_uncertainty"]["note"])
    return rep
