"""One batch least-squares fit of the demo's recorded run with a thrust table (the use case
of ``tpods estimate batch``): the estimate with its total sigma and the sigma's noise and
thrust-table parts. A light module of its own so the batch stage of ``tpods demo``
(:func:`tpods.demo.stages.stage_batch`) can run one fit in another process. Also the
plant's valve switches (saved, and as a run's commands) for the check fit with the truth.
"""

from __future__ import annotations

import dataclasses
import multiprocessing
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from common.errors import UserError
from common.runfolder import Run, read_run
from common.thrust_table import ThrustTable
from estimator.estimate import estimate_run


def batch_row(run: Run, table: ThrustTable) -> dict[str, Any]:
    """Batch LS of ``run`` with ``table`` (what ``tpods estimate batch --clamp`` runs): the
    result (``res``), m and Izz with their total sigma and its noise and thrust parts, and
    the fit's wall time (``fit_s``)."""
    t0 = time.monotonic()
    res = estimate_run(run, table, clamp=True).batch  # the use case of `tpods estimate batch`
    b = res.budget()
    return {"res": res, "mass_kg": res.mass_kg, "izz_kgm2": res.izz_kgm2,
            "mass_sigma_kg": res.mass_sigma_kg, "izz_sigma_kgm2": res.izz_sigma_kgm2,
            "mass_sigma_noise_kg": b["mass"][0], "mass_sigma_thrust_kg": b["mass"][1],
            "izz_sigma_noise_kgm2": b["izz"][0], "izz_sigma_thrust_kgm2": b["izz"][1],
            "converged": res.converged, "thrust_note": res.thrust_note,
            "fit_s": time.monotonic() - t0}


def save_switches(path: Path, switches: Sequence[tuple[float, Sequence[float]]],
                  t0_lab_s: float) -> None:
    """Write the plant's valve switches (``(lab time, duties %)``, as
    :attr:`tpods.plant_loop.PlantLoop.switches`) to ``path`` as ``t,d1..d4`` on the run's
    time base (``t`` = lab time - ``t0_lab_s``, like commands.csv and truth.csv), to the
    nanosecond: when the simulated module's thrusts really changed."""
    rows = [[float(t) - t0_lab_s, *map(float, d)] for t, d in switches]
    n = len(rows[0]) - 1 if rows else 4
    header = ",".join(["t"] + [f"d{j}" for j in range(1, n + 1)])
    np.savetxt(path, np.asarray(rows, float).reshape(-1, n + 1), delimiter=",", header=header,
               comments="", fmt="%.9f")


def switch_run(run: Run, switches_csv: Path) -> Run:
    """``run`` with its commands replaced by the plant's own valve switches
    (:func:`save_switches`): the thrust the simulated module really followed. commands.csv
    holds the player's stamps, which the emulated valves follow a few lab milliseconds late
    (more on a busy machine), an error that no pose noise sigma covers (``tpods demo``'s
    check fit with the true table: a run spinning to hundreds of radians states Izz to
    ~1e-5 relative, and a 1 ms jitter biases it by tens of sigma). Of equal times the
    last row holds (zero-order hold)."""
    sw = np.loadtxt(switches_csv, delimiter=",", skiprows=1, ndmin=2)
    if sw.size == 0:
        raise UserError(f"{switches_csv} holds no valve switch")
    t, duty = np.maximum.accumulate(sw[:, 0]), sw[:, 1:]
    last = np.append(np.diff(t) > 0, True)
    return dataclasses.replace(run, cmd_t=t[last], duty_pct=duty[last], thrust_n=None,
                               thrust_t=None)


def switch_row_json(run_dir: Path, switches_csv: Path, table: ThrustTable) -> dict[str, Any]:
    """:func:`batch_row` of a run folder with the plant's own valve switches as its commands
    (:func:`switch_run`: the check fit with the true table), for another process: the row
    without the result object."""
    row = batch_row(switch_run(read_run(run_dir), switches_csv), table)
    return {k: v for k, v in row.items() if k != "res"}


def _child(conn, run_dir: Path, table: ThrustTable) -> None:
    try:
        conn.send(("ok", segments_row_json(run_dir, table)))
    except BaseException as exc:  # noqa: BLE001 - handed to the parent, which raises it
        conn.send(("error", exc))
    finally:
        conn.close()


class BackgroundFit:
    """:func:`segments_row_json` of ``run_dir`` with ``table`` in a process of its own (spawned:
    the parent may hold threads), started at once; :meth:`result` waits for it and raises
    what the fit raised; :meth:`stop` ends it early (on every exit path of the caller). A
    script that uses it needs the ``if __name__ == "__main__":`` guard spawning asks for
    (``tpods`` and ``python -m tpods.cli`` have it)."""

    def __init__(self, run_dir: Path, table: ThrustTable) -> None:
        ctx = multiprocessing.get_context("spawn")
        self._recv, send = ctx.Pipe(duplex=False)
        self._proc = ctx.Process(target=_child, args=(send, Path(run_dir), table), daemon=True,
                                 name="tpods-demo-batch-fit")
        self._proc.start()
        send.close()

    def result(self) -> dict[str, Any]:
        try:
            kind, value = self._recv.recv()
        except EOFError:
            raise UserError("the batch fit's process ended without a result") from None
        self._proc.join()
        if kind == "error":
            raise value
        return value

    def stop(self) -> None:
        if self._proc.is_alive():
            self._proc.terminate()
            self._proc.join(5)
        self._recv.close()


def segments_row_json(run_dir: Path, table: ThrustTable, health: bool = True) -> dict[str, Any]:
    """The bench-table fit of the demo's run by segments (what ``tpods estimate batch
    --segments auto --thruster-health`` runs, :mod:`estimator.shooting`), for another process:
    m and Izz with their sigma, the misfit the fit names and, with ``health``, the thruster
    health check (:func:`health_json`; else the caller adds it as ``health``). The thrust
    table's own stated uncertainty is not in this sigma (``sigma_note`` says so)."""
    from estimator.shooting.fit import fit_segments
    from estimator.shooting.vehicles import module_vehicle

    t0 = time.monotonic()
    run = read_run(run_dir)
    f = fit_segments(run.pose_t, run.pose, module_vehicle(table), run.cmd_t, run.duty_pct,
                     names=("mass", "izz"), clamp=True)
    s = f.sigma
    return {"method": "segments", "mass_kg": f.values["mass"], "izz_kgm2": f.values["izz"],
            "mass_sigma_kg": s["mass"]["total"], "izz_sigma_kgm2": s["izz"]["total"],
            "mass_sigma_noise_kg": s["mass"]["noise"], "mass_sigma_thrust_kg": s["mass"]["thrust"],
            "izz_sigma_noise_kgm2": s["izz"]["noise"], "izz_sigma_thrust_kgm2": s["izz"]["thrust"],
            "converged": f.converged, "segments": f"{f.plan.n} x {f.plan.length_s:g} s",
            "misfit": list(f.warnings), "sigma_note": f.sigma_note,
            "fit_s": time.monotonic() - t0, "res_dict": f.to_dict(),
            **({"health": health_json(run_dir, table)} if health else {})}


def health_json(run_dir: Path, table: ThrustTable) -> dict[str, Any]:
    """The thruster health check of the demo's run with ``table``, for another process: its
    lines, the flagged thrusters, the loss it would name, the lowest thruster."""
    from estimator.shooting.health import thruster_health
    from estimator.shooting.vehicles import module_vehicle

    t0 = time.monotonic()
    run = read_run(run_dir)
    h = thruster_health(run.pose_t, run.pose, module_vehicle(table), run.cmd_t, run.duty_pct,
                        clamp=True)
    return {"lines": h.lines(), "resolution": h.resolution,
            "lowest": min(((t.name, t.efficiency) for t in h.thrusters), key=lambda x: x[1]),
            "flagged": {t.name: t.verdict for t in h.thrusters if t.verdict != "ok"},
            "thrusters": [t.to_dict() for t in h.thrusters], "health_s": time.monotonic() - t0}


def segment_lines(r: dict[str, Any]) -> list[str]:
    """What a :func:`segments_row_json` row says beyond its numbers: the misfit its fit names,
    the thrusters the health check flags (or the smallest loss it resolves on this run),
    what its sigma leaves out. Empty for another row."""
    if r.get("method") != "segments":
        return []
    out = [f"the fit names its misfit: {w}" for w in r["misfit"]]
    h = r["health"]
    flagged = h["flagged"]
    if flagged:
        out += ["thruster health: " + line.strip() for line in h["lines"][1:]
                if line.split()[0] in flagged]
    else:
        low = h["lowest"]
        out.append(f"thruster health: no thruster stands out; on this run a loss of "
                   f"{h['resolution'] * 100:.1f} % or more would be named, not less (the lowest, "
                   f"{low[0]}, gives {low[1] * 100:.1f} % of the median thruster's thrust)")
    if r.get("sigma_note"):
        out.append(f"sigma: {r['sigma_note']}")
    return out
