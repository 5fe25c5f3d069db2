"""The side processes of ``tpods demo``: two spawned workers started with the demo,
which import the estimator, the fits and matplotlib while the characterisation dwells (after
:data:`WARM_DELAY_S`), and then take work off the demo's critical path: the mass and bifilar
stages (beside the characterisation), the bench figures (beside the calibration flight's
start), two of the batch stage's three fits (from the module run's sealed recording on,
beside the live estimator's final fit), the run's figures and the residual figure.
Processes, not threads: the simulated plant runs in the demo's main process and a thread
would take its interpreter lock (late valve switches). Between jobs the workers wait on a
pipe and take no CPU, also during the paced flights.

Each job runs through :func:`timed_call`: its result and its wall time in the worker, which
the demo's stage table shows as work done beside the stages (:meth:`SideWork.seconds`).
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

WORKERS = 2
"""One per core of a small lab PC: two jobs beside the main process at most."""


WARM_DELAY_S = 1.0
"""How long a worker waits before its imports: the demo's own imports and the first steps of
the characterisation go first (on two cores, four processes importing at once delayed the
session's start by a few tenths of a second)."""


def _warm() -> None:
    """Each worker's start: the modules its jobs need, imported before any job is sent
    (after :data:`WARM_DELAY_S`)."""
    time.sleep(WARM_DELAY_S)
    import matplotlib

    matplotlib.use("Agg")
    import bench.plots  # noqa: F401
    import estimator.reports.plots.batch  # noqa: F401
    import tpods.demo.fit  # noqa: F401
    import tpods.demo.report  # noqa: F401


def _ready() -> None:
    """A job that only makes the pool start a worker (spawned on demand, one per job)."""
    time.sleep(0.2)


def timed_call(fn: Callable[..., Any], *args: Any) -> tuple[Any, float]:
    """``fn(*args)`` and its wall time, s (run in a worker)."""
    t0 = time.monotonic()
    return fn(*args), time.monotonic() - t0


def bench_figures(fit, raw, steps, d: Path, truth) -> list[Path]:
    """The characterisation's figures (what :func:`tpods.demo.bench.stage_bench` drew)."""
    from bench.plots import plot_fit_orders, plot_time_series

    return [plot_fit_orders(fit, d / "thrust_fit_orders.png", truth=truth),
            plot_time_series(raw, d / "thrust_timeseries.png", steps)]


def residual_figure(t, residuals, path: Path, title: str) -> Path:
    """The batch fit's residual figure (what :func:`tpods.demo.stages.stage_batch` drew)."""
    from estimator.reports.plots.batch import plot_residuals

    return plot_residuals(t, residuals, path, title=title)


class SideWork:
    """The demo's side workers: :meth:`submit` a job (a module-level function and picklable
    arguments) and get a future of its result; :meth:`seconds` notes each job's wall time
    under a label; :meth:`close` ends the workers on every exit path."""

    def __init__(self, workers: int = WORKERS) -> None:
        self._pool = cf.ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                                            initializer=_warm)
        for _ in range(workers):
            self._pool.submit(_ready)
        self.side_s: dict[str, float] = {}
        """Wall time of the jobs, s, by label (the stage table's rows of side work)."""

    def submit(self, label: str, fn: Callable[..., Any], *args: Any) -> cf.Future:
        """Run ``fn(*args)`` in a worker; the future's result is ``fn``'s."""
        outer: cf.Future = cf.Future()

        def done(f: cf.Future) -> None:
            if f.cancelled():
                outer.cancel()
            elif f.exception() is not None:
                outer.set_exception(f.exception())
            else:
                res, sec = f.result()
                self.side_s[label] = self.side_s.get(label, 0.0) + sec
                outer.set_result(res)

        self._pool.submit(timed_call, fn, *args).add_done_callback(done)
        return outer

    def close(self) -> None:
        """End the workers (a job still running is terminated)."""
        procs = list((getattr(self._pool, "_processes", None) or {}).values())
        self._pool.shutdown(wait=False, cancel_futures=True)  # idle workers exit at once
        for p in procs:
            p.join(2)
            if p.is_alive():
                p.terminate()
                p.join(5)
