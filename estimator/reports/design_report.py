"""The use case of ``tpods design`` (D-optimal input design for m and Izz, or for a
structure's m, Izz, cx, cy): :func:`design_settings` checks the options and builds the
:class:`estimator.batch.design.DesignSettings` with the thrust table, :func:`design_inputs`
scores the compared inputs, searches the phase-shifted sines and returns a
:class:`DesignReport`, which writes the design into a folder (commands.csv of the best
input, design.json, sensitivities_best.png and sensitivities_paper.png), gives its JSON
object and the console ``lines()``.

Units: durations s, rates Hz, mass kg, Izz kg m^2, table size and margin m, yaw rate rad/s,
pose noise m and deg, frequencies rad/s. A progress bar on stderr while searching;
nothing else is printed. A user's error raises :class:`common.errors.UserError` naming
the command's options.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from common.constants import PAPER_IZZ_KGM2, PAPER_MASS_KG
from common.errors import UserError


def design_settings(*, duration_s: float = 120.0, cmd_rate_hz: float = 50.0,
                    pose_rate_hz: float = 120.0, mass_kg: float | None = None,
                    izz_kgm2: float | None = None, table_size_m: Sequence[float] = (2.0, 2.0),
                    margin_m: float = 0.0, max_yaw_rate: float | None = None,
                    noise_pos_m: float = 0.01, noise_yaw_deg: float = 1.0,
                    structure: str | Path | None = None, thrust_table: str | Path | None = None,
                    candidates: int = 64, refine: int = 2, refine_evals: int = 60,
                    omega_range: Sequence[float] = (0.2, 4.0), compare: Sequence[str] = (),
                    design_for: str = "mass-izz") -> tuple[Any, Any]:
    """(thrust table, :class:`estimator.batch.design.DesignSettings`) of a design: the
    plant ``mass_kg``, ``izz_kgm2`` (default the paper's module; a structure's [body], else
    its layout), the workspace ``table_size_m`` (W, H) less ``margin_m``; the search's size
    (``candidates``, ``refine`` x ``refine_evals``, ``compare``) checked against memory."""
    from common.thrust_table import load_thrust_table
    from estimator.batch.design import DesignSettings
    from estimator.plant.model import PlantParams
    from estimator.plant.size_checks import check_design_size

    if candidates < 1 or refine < 0 or refine_evals < 1:
        raise UserError("--candidates and --refine-evals must be >= 1, --refine >= 0")
    if omega_range[0] <= 0 or omega_range[1] <= omega_range[0]:
        raise UserError("--omega-range must be LO,HI with 0 < LO < HI")
    if min(table_size_m) <= 2 * margin_m:
        raise UserError("--table-size must exceed twice the --margin")
    layout = None
    if structure:
        from common.layout_files import load_layout

        known = load_layout(structure).body.known()
        if all(n in known for n in ("mass", "izz", "cx", "cy")):
            raise UserError(f"{structure}: [body] gives mass, Izz and the centre of mass as "
                            "known: nothing left to design for (give a value a sigma, or drop it)")
    check_design_size(duration_s, pose_rate_hz, cmd_rate_hz, candidates, refine, refine_evals,
                      len(compare))
    table = load_thrust_table(thrust_table)
    plant = PlantParams(mass_kg or PAPER_MASS_KG, izz_kgm2 or PAPER_IZZ_KGM2)
    if structure:
        if design_for == "thrust-calibration":
            raise UserError("--for thrust-calibration is not built for structures yet")
        if compare:
            raise UserError("--compare takes single-module inputs; a structure design "
                            "compares with the phase-shifted sine over all its channels")
        layout = load_layout(structure)
        g = layout.initial_guess()
        body = layout.body
        if layout.kind == "vehicle" and not layout.is_single_at_origin and (
                (mass_kg is None and body.mass_kg is None) or (izz_kgm2 is None and body.izz_kgm2 is None)):
            # its initial guess is the paper's 2.3 kg module: a design for another body
            raise UserError(f"{structure}: states no [body] mass_kg and izz_kgm2: give "
                            "--mass and --izz (the design depends on them; the paper's module "
                            "is not this vehicle)")
        plant = PlantParams(mass_kg if mass_kg is not None else g["mass"],
                            izz_kgm2 if izz_kgm2 is not None else g["izz"], cx=g["cx"], cy=g["cy"])
    return table, DesignSettings(duration_s, cmd_rate_hz, pose_rate_hz, noise_pos_m,
                                 math.radians(noise_yaw_deg), plant, tuple(table_size_m),
                                 margin_m, max_yaw_rate, layout)


@dataclass
class DesignReport:
    """A design: the search's result ``res`` (``best``, ``paper``, ``evaluated``), the
    ``compared`` inputs' evaluations, the ``settings``, the ``structure`` file (or None)."""

    res: Any
    compared: list[Any]
    settings: Any
    structure: str | Path | None = None
    out: dict[str, Any] = field(default_factory=dict)

    def write(self, d: Path, final: Path) -> dict[str, Any]:
        """Write the design into ``d`` (the temporary folder that becomes ``final``); returns
        the JSON object of design.json."""
        from estimator.reports.plots.batch import plot_sensitivities

        best, st = self.res.best, self.settings
        n_ch = best.duty_pct.shape[1]
        np.savetxt(d / "commands.csv", np.column_stack([best.cmd_t, best.duty_pct]), delimiter=",",
                   header="t," + ",".join(f"d{i + 1}" for i in range(n_ch)), comments="", fmt="%.10g")
        if self.structure:
            import shutil

            shutil.copyfile(self.structure, d / "structure.toml")
        mass, izz = st.plant.mass_kg, st.plant.izz_kgm2
        self.out = {
            "best": _row(best), "paper": _row(self.res.paper),
            "compared": [_row(e) for e in self.compared], "evaluated": self.res.evaluated,
            "improvement_logdet": best.logdet - self.res.paper.logdet,
            "settings": {"duration_s": st.duration_s, "cmd_rate_hz": st.cmd_rate_hz,
                         "pose_rate_hz": st.pose_rate_hz, "table_size_m": list(st.table_size_m),
                         "margin_m": st.margin_m, "max_yaw_rate_rad_s": st.max_yaw_rate_rad_s,
                         "mass_kg": mass, "izz_kgm2": izz},
            "criterion_parameters": list(best.crlb.names),
            "commands_csv": str(final / "commands.csv")}
        (d / "design.json").write_text(json.dumps(self.out, indent=2) + "\n")
        for e, name in ((best, "sensitivities_best.png"), (self.res.paper, "sensitivities_paper.png")):
            t = np.arange(len(e.crlb.sens_x)) / st.pose_rate_hz
            plot_sensitivities(t, e.crlb.sens_x[:, :, :2], e.crlb.names[:2], [mass, izz],
                               d / name, title=e.label)
        return self.out

    def lines(self, final: Path) -> list[str]:
        """The best input beside the paper's and the compared ones, written to ``final``."""
        res, best, st = self.res, self.res.best, self.settings
        half = np.asarray(st.table_size_m) / 2 - st.margin_m
        lines = [f"D-optimal design over {st.duration_s:g} s ({res.evaluated} sequences scored; "
                 f"workspace |x|,|y| <= {half[0]:g}, {half[1]:g} m from the start)",
                 f"  {'input':<44} {'log det':>9} {'sd(m) kg':>10} {'sd(Izz)':>10} "
                 f"{'excursion x,y m':>17}  fits"]
        for e in [res.paper, *self.compared, best]:
            lab = e.label if len(e.label) <= 44 else e.label[:41] + "..."
            lines.append(f"  {lab:<44} {e.logdet:9.3f} {e.crlb.mass_sigma_kg:10.3g} "
                         f"{e.crlb.izz_sigma_kgm2:10.3g} {e.excursion_m[0]:8.2f},"
                         f"{e.excursion_m[1]:7.2f}  {'yes' if e.feasible else 'NO'}")
        return lines + [
            f"  best: {best.spec.describe()}",
            f"  log det gain over the paper's input: {best.logdet - res.paper.logdet:+.3f}",
            f"  wrote {final / 'commands.csv'} (play it or simulate it with tpods sim --input), "
            "design.json"]


def _row(e) -> dict[str, Any]:
    """One scored input of design.json."""
    return {"label": e.label, "logdet_info": e.logdet, "feasible": e.feasible,
            "max_yaw_rate_rad_s": float(np.abs(e.crlb.states[:, 5]).max()),
            "excursion_x_m": e.excursion_m[0], "excursion_y_m": e.excursion_m[1],
            "crlb_mass_sigma_kg": e.crlb.mass_sigma_kg,
            "crlb_izz_sigma_kgm2": e.crlb.izz_sigma_kgm2,
            **({"crlb_com_x_sigma_m": e.crlb.sigma_of("cx"),
                "crlb_com_y_sigma_m": e.crlb.sigma_of("cy")} if "cx" in e.crlb.names else {}),
            **({"amplitude_pct": e.spec.amplitude_pct, "omega_rad_s": e.spec.omega_rad_s,
                "phases_rad": list(e.spec.phases_rad), "mean_pct": e.spec.mean_pct}
               if e.spec else {})}


def design_inputs(table, settings, *, candidates: int = 64, refine: int = 2,
                  refine_evals: int = 60, omega_range: Sequence[float] = (0.2, 4.0),
                  compare: Sequence[str] = (), seed: int = 0, structure: str | Path | None = None,
                  progress: bool = True) -> DesignReport:
    """Score ``compare`` (phase-sine, translate-rotate or commands.csv paths) and search the
    phase-shifted sines (``candidates`` random, ``refine`` Nelder-Mead refinements of
    ``refine_evals`` evaluations, frequencies in ``omega_range``) under ``settings``."""
    from tqdm import tqdm

    from estimator.batch.design import evaluate_commands, search
    from estimator.plant.inputs import make_input

    compared = []
    for spec in compare:
        cmd_t, duty = make_input(spec, settings.duration_s, settings.cmd_rate_hz)
        try:
            compared.append(evaluate_commands(cmd_t, duty, table, settings, spec))
        except UserError as exc:
            raise UserError(f"{spec}: {exc}") from None
    total = 1 + candidates + refine * refine_evals
    with tqdm(total=total, desc="design", unit="eval", leave=False,
              disable=None if progress else True) as bar:
        res = search(table, settings, n_random=candidates, n_refine=refine,
                     refine_evals=refine_evals, omega_range=tuple(omega_range), seed=seed,
                     progress=bar.update)
    return DesignReport(res, compared, settings, structure)
