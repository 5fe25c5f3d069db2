"""Shorter garbage-collector pauses for the latency-critical loops: the live
estimator, the emulated lab's plant and valve controllers, the player.

A full collection scans every container object of the process. Before a run starts,
:func:`frozen_heap` collects once and moves everything that exists into the permanent
generation (``gc.freeze``): the collections during the run then scan only what the run
made. Measured: the live estimator's one full collection of a 15 s run at 1 kHz took
12-17 ms (docs/bench.md); after the demo's bench stage a full collection takes 35-46 ms
on an idle machine, and a 277 ms stall of the in-process plant once put a valve change a
quarter of a second late and the calibration flight's factors 15 % off (tpods/demo/fidelity.py).
"""

from __future__ import annotations

import contextlib
import gc
from collections.abc import Iterator


@contextlib.contextmanager
def frozen_heap() -> Iterator[None]:
    """Collect, freeze the objects that exist, run the block, unfreeze (on every path)."""
    gc.collect()
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()
