"""The use case of ``tpods estimate montecarlo``: :func:`montecarlo_study` runs the
consistency study of the module's EKF (:func:`estimator.montecarlo.run_montecarlo`: m and
Izz drawn within +/- ``spread``, all runs vectorised) or, with a ``structure``, of batch
least squares on the structure (:func:`estimator.montecarlo_structure.run_structure_montecarlo`)
and returns a :class:`McReport`: the summary (``json_text()``), the console ``lines()`` and
``write(main, folder)`` of montecarlo.json (and, in a folder, history.csv, runs.csv and the
figures mc_runs.png, mc_averages.png; a structure's runs.csv).

Units: durations s, rates Hz, spreads relative (m, Izz) and m (cx, cy), pose noise m and
deg. The study shows a progress bar on stderr; Ctrl-C stops it with the statistics so far
(``interrupted``). A user's error raises :class:`common.errors.UserError`.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from common.errors import UserError


@dataclass
class McReport:
    """A Monte Carlo study: ``result`` (an ``McResult`` or ``StructureMcResult``), its
    ``summary`` and ``config``; ``structure`` True for a structure's study."""

    result: Any
    summary: dict[str, Any]
    config: Any
    structure: bool = False

    @property
    def interrupted(self) -> str | None:
        """Where Ctrl-C stopped the study, or None."""
        if not self.result.interrupted:
            return None
        return (f"after {self.result.done} runs" if self.structure
                else f"at t = {self.result.t[-1]:.2f} s")

    def json_text(self) -> str:
        return json.dumps(self.summary)

    @property
    def folder_files(self) -> str:
        return ", runs.csv" if self.structure else ", history.csv, runs.csv, mc_runs.png, mc_averages.png"

    def write(self, main: Path, folder: Path | None) -> None:
        """montecarlo.json to ``main``; with a ``folder`` (else None) the tables and figures."""
        res, cfg = self.result, self.config
        doc = ({"summary": self.summary, "config": cfg.to_dict(), "failed_runs": res.messages}
               if self.structure else {"summary": self.summary, "config": _config_dict(cfg)})
        main.write_text(json.dumps(doc, indent=2, default=str) + "\n")
        if folder is None:
            return
        if self.structure:
            cols, data = res.runs_table()
            np.savetxt(folder / "runs.csv", data, delimiter=",", header=",".join(cols),
                       comments="", fmt="%.10g")
            return
        from estimator.reports.plots.ekf import plot_mc_averages, plot_mc_runs

        cols, data = res.history_table()
        np.savetxt(folder / "history.csv", data, delimiter=",", header=",".join(cols), comments="",
                   fmt="%.8g")
        runs = np.column_stack([np.arange(cfg.runs), res.truth, res.final_err[:, 6:8],
                                res.final_sigma[:, 6:8], res.rmse])
        np.savetxt(folder / "runs.csv", runs, delimiter=",", comments="", fmt="%.8g",
                   header="run,mass_kg,izz_kgm2,final_err_mass_kg,final_err_izz_kgm2,"
                          "final_sigma_mass_kg,final_sigma_izz_kgm2,rmse_mass_kg,rmse_izz_kgm2")
        tag = f"{cfg.method}{' (' + cfg.ls_start + ')' if cfg.method == 'ls-ekf' else ''}"
        plot_mc_runs(res.t, res.ex_err, res.ex_sigma, folder / "mc_runs.png",
                     title=f"Monte Carlo {tag}: {res.ex_err.shape[0]} of {cfg.runs} runs")
        plot_mc_averages(res, folder / "mc_averages.png",
                         title=f"Monte Carlo {tag}, {cfg.runs} runs, spread +/-{cfg.spread:g}")

    def lines(self) -> list[str]:
        """The text report."""
        if self.structure:
            from estimator.montecarlo_structure import summary_lines

            return summary_lines(self.result)
        s, cfg = self.summary, self.config
        b, bf = s["nees_param_bounds"], s["nees_full_bounds"]
        lines = [
            f"Monte Carlo: {cfg.runs} runs x {cfg.duration_s:g} s, {cfg.input}, method {cfg.method}"
            f"{' (' + cfg.ls_start + ')' if cfg.method == 'ls-ekf' else ''}, spread +/-{cfg.spread:g}, "
            f"{self.result.elapsed_s:.1f} s",
            f"  final bias   mass {s['final_bias_mass_kg']:+.3g} kg, Izz {s['final_bias_izz_kgm2']:+.3g} kg m^2",
            f"  final std    mass {s['final_std_mass_kg']:.3g} (filter sigma {s['final_sigma_mass_kg']:.3g}), "
            f"Izz {s['final_std_izz_kgm2']:.3g} (filter sigma {s['final_sigma_izz_kgm2']:.3g})",
            f"  avg NEES m,Izz  mean {s['nees_param_mean']:.3g}, bounds [{b[0]:.3g}, {b[1]:.3g}], "
            f"inside {100 * s['nees_param_inside_frac']:.0f} % of times",
            f"  avg NEES state  mean {s['nees_full_mean']:.3g}, bounds [{bf[0]:.3g}, {bf[1]:.3g}], "
            f"inside {100 * s['nees_full_inside_frac']:.0f} % of times",
            f"  final errors inside 3 sigma: mass {100 * s['within_3sigma_mass']:.1f} %, "
            f"Izz {100 * s['within_3sigma_izz']:.1f} %; runs with final (m, Izz) NEES above the "
            f"99.9 % chi-square point: {100 * s['final_outlier_frac']:.1f} %"]
        if cfg.filter.underweight > 0:
            lines.append(f"  underweighted updates: {100 * s['underweighted_frac']:.2f} %")
        if s["ls_failed"]:
            lines.append(f"  {s['ls_failed']} runs whose LS fit failed started from the ekf "
                         "initialisation")
        return lines


def _config_dict(cfg) -> dict[str, Any]:
    from estimator.montecarlo import config_dict

    return config_dict(cfg)


def check_montecarlo(*, runs: int, duration_s: float, pose_rate_hz: float, cmd_rate_hz: float,
                     structure: Any = None, method: str = "ekf",
                     noise_pos_m: float | None = None, noise_yaw_deg: float | None = None) -> None:
    """The checks made before anything is allocated or written: the size, the options a
    module's study or a structure's does not take."""
    from estimator.plant.size_checks import check_montecarlo_size

    check_montecarlo_size(duration_s, pose_rate_hz, cmd_rate_hz, runs, structure is not None)
    if structure is not None:
        if method != "ekf":
            raise UserError("--method: a structure's Monte Carlo fits batch LS (drop --method)")
        return
    for opt, v in (("noise-pos", noise_pos_m), ("noise-yaw-deg", noise_yaw_deg)):
        if v is not None:
            raise UserError(f"--{opt} is for --structure runs; the module's "
                            "filter Monte Carlo simulates 1 cm / 1 deg pose noise")


def montecarlo_study(*, runs: int = 500, spread: float = 0.5, duration_s: float = 120.0,
                     input: str = "phase-sine", method: str = "ekf", seed: int = 0,
                     pose_rate_hz: float = 120.0, cmd_rate_hz: float = 50.0, drop: float = 0.0,
                     structure: str | Path | None = None, com_spread_m: float = 0.02,
                     noise_pos_m: float | None = None, noise_yaw_deg: float | None = None,
                     filter_options: Any = None, progress: bool = True) -> McReport:
    """The study (see the module's docstring); ``filter_options`` an
    :class:`estimator.estimate.FilterOptions` (default the paper's filter without process
    noise, LS window 20 s); a structure's study takes ``com_spread_m`` and the pose noise
    (default 0.01 m, 1 deg), not the filter options."""
    check_montecarlo(runs=runs, duration_s=duration_s, pose_rate_hz=pose_rate_hz,
                     cmd_rate_hz=cmd_rate_hz, structure=structure, method=method,
                     noise_pos_m=noise_pos_m, noise_yaw_deg=noise_yaw_deg)
    if structure is not None:
        from common.layout_files import load_layout
        from estimator.montecarlo_structure import StructureMcConfig, run_structure_montecarlo

        cfg = StructureMcConfig(
            load_layout(structure), runs=runs, spread=spread, com_spread_m=com_spread_m,
            duration_s=duration_s, input=input, seed=seed, pose_rate_hz=pose_rate_hz,
            cmd_rate_hz=cmd_rate_hz, drop=drop,
            noise_pos_m=noise_pos_m if noise_pos_m is not None else 0.01,
            noise_yaw_rad=math.radians(noise_yaw_deg if noise_yaw_deg is not None else 1.0))
        res = run_structure_montecarlo(cfg, progress=progress)
        return McReport(res, res.summary(), cfg, structure=True)
    from estimator.estimate import FilterOptions, filter_config
    from estimator.montecarlo import MC_FILTER, McConfig, run_montecarlo

    fo = filter_options if filter_options is not None else FilterOptions(preset="no-process-noise")
    cfg_f = filter_config(fo, MC_FILTER if fo.preset == "no-process-noise" else None)
    if method == "ls-ekf" and fo.ls_window_s >= duration_s:
        raise UserError("--ls-window must be shorter than --duration")
    try:
        cfg = McConfig(runs=runs, spread=spread, duration_s=duration_s, input=input, method=method,
                       seed=seed, pose_rate_hz=pose_rate_hz, cmd_rate_hz=cmd_rate_hz, drop=drop,
                       ls_window_s=fo.ls_window_s, ls_start=fo.ls_start, filter=cfg_f)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    res = run_montecarlo(cfg, progress=progress)
    return McReport(res, res.summary(), cfg)
