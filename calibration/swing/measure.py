"""Izz of a hung body from one swing recording: the use case behind ``tpods calibrate
bifilar|trifilar``, callable from a notebook.

:func:`measure_izz` takes a :class:`calibration.suspension.Suspension` (kg, m, their
standard uncertainties) and one source: stopwatch ``times`` (s, of ``cycles`` full
oscillations each), a ``poses`` file (poses.csv t,x,y,psi or its run folder: the yaw
trace), a gyro's ``rates`` log or any ``trace`` proportional to the angle (CSV time,
value). It checks the source, fits it (:mod:`calibration.swing.trace_fit`, Eq. 19 on
timings) and, given ``out``, writes result.json and the plots (a folder) or the JSON alone
(FILE.json). It prints nothing: the :class:`SwingIzz` carries the result, a description
of its source, the JSON document, the files written and the warnings; a user error raises
:class:`common.errors.UserError`.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from calibration.suspension import Suspension, izz_trifilar_from_times
from calibration.swing import bifilar
from calibration.swing.trace_fit import fit_pose_trace, fit_swing
from calibration.swing.trace_io import RATE_UNITS_RAD_S, read_swing_csv
from calibration.swing.units import AMPLITUDE_LIMIT_DEG, swing_presence_problem, swing_units_problem
from common.errors import UserError, Warnings
from common.outputs import result_output
from common.runfolder import POSE_COLUMNS, read_table


@dataclass
class SwingIzz:
    """A pendulum's Izz: ``result`` (an :class:`calibration.swing.bifilar_eq19.IzzResult` or a
    trace fit's result), ``source`` (one line: what was fitted), ``doc`` (its JSON form),
    ``files`` (written), ``warnings`` (the source's, then the fit's)."""

    result: Any
    source: str
    doc: dict
    files: list[Path] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)


def read_yaw(path_text: str | Path):
    """(t s, psi rad, the file) of a poses.csv or of a run folder's."""
    path = Path(path_text)
    if path.is_dir():
        path = path / "poses.csv"
    v = read_table(path, POSE_COLUMNS)
    return np.ascontiguousarray(v[:, 0]), np.ascontiguousarray(v[:, 3]), path


def _window(window, t, y):
    if not window:
        return t, y
    t0, t1 = window
    keep = (t >= (-math.inf if t0 is None else t0)) & (t <= (math.inf if t1 is None else t1))
    return t[keep], y[keep]


def check_log_options(rates, trace, columns, time_unit, sample_rate, rate_unit, trace_scale,
                      amplitude_max) -> None:
    """Refuse a log option given without the log it is for, or out of its range."""
    log_only = [o for o, v, d in (("--columns", columns, None), ("--time-unit", time_unit, "s"),
                                  ("--sample-rate", sample_rate, None)) if v != d]
    if log_only and not (rates or trace):
        raise UserError(f"{', '.join(log_only)}: only for --rates or --trace logs")
    if rate_unit != "rad/s" and not rates:
        raise UserError("--rate-unit is for --rates logs")
    if (trace_scale is not None or amplitude_max != 15.0) and not trace:
        raise UserError("--trace-scale and --amplitude-max are for --trace logs")
    if amplitude_max > AMPLITUDE_LIMIT_DEG:
        raise UserError(f"--amplitude-max {amplitude_max:g} deg: a swing of the strings "
                        f"beyond {AMPLITUDE_LIMIT_DEG:g} deg winds them over each other, where "
                        "the pendulum model does not hold (swings are released at 5-20 deg)")
    if trace_scale is not None and not (math.isfinite(trace_scale) and trace_scale):
        raise UserError(f"--trace-scale must be a non-zero finite number, got {trace_scale}")


def measure_izz(s: Suspension, *, times: Sequence[float] | None = None, cycles: int = 10,
                poses: str | Path | None = None, rates: str | Path | None = None,
                trace: str | Path | None = None, u_timing: float = 0.0,
                window: tuple[float | None, float | None] | None = None, rise_ke: bool = True,
                columns: str | None = None, time_unit: str = "s", rate_unit: str = "rad/s",
                sample_rate: float | None = None, trace_scale: float | None = None,
                amplitude_max: float = 15.0, out: str | Path | None = None,
                force: bool = False,
                on_warning: Callable[[str], object] | None = None) -> SwingIzz:
    """Izz of the body on suspension ``s`` from exactly one of ``times``, ``poses``,
    ``rates`` (rad/s by default, ``rate_unit``) or ``trace`` (``trace_scale`` rad per unit,
    else the period only). ``window`` (s) keeps the samples inside it; ``rise_ke`` counts
    the kinetic energy of the body's rise; ``out``: a folder (result.json and plots) or
    FILE.json, replaced only with ``force``. ``on_warning(line)`` hears each warning as it
    arises."""
    if sum(x is not None for x in (times, poses, rates, trace)) != 1:
        raise UserError("give one source: --times, --poses, --rates or --trace")
    check_log_options(rates, trace, columns, time_unit, sample_rate, rate_unit, trace_scale,
                      amplitude_max)
    out_folder = result_output(None if out is None else str(out), "result.json", force=force,
                               command=f"tpods calibrate {s.kind}")
    warnings = Warnings(on_warning)
    res, source = _estimate(s, times, cycles, poses, rates, trace, u_timing, window, rise_ke,
                            columns, time_unit, rate_unit, sample_rate, trace_scale,
                            amplitude_max, warnings)
    doc = res.to_dict()
    doc.setdefault("warnings", [])
    files = _write(res, doc, out_folder) if out_folder is not None else []
    warnings += getattr(res, "warnings", ())
    return SwingIzz(res, source, doc, files, warnings)


def _estimate(s, times, cycles, poses, rates, trace, u_timing, window, rise_ke, columns,
              time_unit, rate_unit, sample_rate, trace_scale, amplitude_max, warnings):
    if times is not None:
        if s.kind == "trifilar":
            res = izz_trifilar_from_times(times, cycles, s, u_timing_s=u_timing)
        else:
            res = bifilar.izz_from_times(times, cycles, s.mass_kg, s.arm_m, s.length_m,
                                         u_timing_s=u_timing, u_mass_kg=s.u_mass_kg,
                                         u_spacing_m=s.u_arm_m, u_length_m=s.u_length_m,
                                         tare_izz_kgm2=s.tare_izz_kgm2, u_tare_kgm2=s.u_tare_kgm2,
                                         g=s.g, u_g=s.u_g)
        return res, f"{len(times)} timings of {cycles} oscillations"
    if poses:
        t, y, path = read_yaw(poses)
        signal = "angle"
    else:
        path = Path(rates or trace)
        scale = RATE_UNITS_RAD_S[rate_unit] if rates else (trace_scale or 1.0)
        t, y, skipped = read_swing_csv(path, "rate" if rates else "value", columns,
                                       time_unit=time_unit, value_scale=scale,
                                       sample_rate_hz=sample_rate)
        if skipped:
            warnings.append(f"{path}: {skipped} rows with an empty cell skipped")
        signal = "rate" if rates else ("angle" if trace_scale else "signal")
    t, y = _window(window, t, y)
    problem = swing_presence_problem(t, y) or swing_units_problem(t, y, signal)
    if problem is not None:
        raise UserError(f"{path}: {problem}")
    try:
        if signal == "angle" and poses:
            res = fit_pose_trace(t, y, s, vertical_ke=rise_ke)
        else:
            res = fit_swing(t, y, signal, s, vertical_ke=rise_ke, amplitude_max_deg=amplitude_max)
    except UserError as exc:
        raise UserError(f"{path}: {exc}") from None
    return res, str(path)


def _write(res, doc: dict, out_folder) -> list[Path]:
    """result.json (and, in a folder, budget.png and fit.png); the final paths."""
    from calibration import plots  # lazy: matplotlib only when plots are written

    files = []
    with out_folder.writing_main() as (main, out):  # out: None for --out FILE.json
        main.write_text(json.dumps(doc, indent=2, default=float) + "\n")
        files.append(main)
        if out is not None:
            files.append(plots.plot_budget(res, out / "budget.png"))
            if hasattr(res, "psi_fit"):
                files.append(plots.plot_trace_fit(res, out / "fit.png"))
            elif hasattr(res, "y_fit"):
                files.append(plots.plot_signal_fit(res, out / "fit.png"))
        files = [out_folder.final(p) for p in files]
    return files
