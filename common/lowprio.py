"""The scheduling of a helper process that writes beside a live loop (a recording process).

A live estimator's thread sleeps until the next pose and must run the moment it arrives.
A writer process at an ordinary priority, or merely at nice 10, can hold the core it
wants for a scheduler slice (measured: 0.2-0.7 ms more at the p99 of pose to estimate on 2
cores). :func:`background` puts the calling process in ``SCHED_IDLE``: it runs only on
a core nothing else wants, and any woken thread of an ordinary process takes its core at
once. :class:`LagGuard` undoes that when the writer falls behind (the cores stay busy for
long): a batch handed over more than :data:`LAG_S` ago puts it back to the ordinary policy
at nice 10, where the operating system allows that (``RLIMIT_NICE``; else it stays idle
and catches up when the cores free).
"""

from __future__ import annotations

import contextlib
import os
import time

LAG_S = 0.5
"""A batch older than this (s) when the writer reads it: the writer is falling behind."""
NICE = 10


def background() -> None:
    """Lower the calling process: nice :data:`NICE`, then ``SCHED_IDLE`` where there is one."""
    with contextlib.suppress(OSError, AttributeError):
        os.nice(NICE)
    with contextlib.suppress(OSError, AttributeError):
        os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))


class LagGuard:
    """Back to the ordinary policy (nice :data:`NICE`) once a batch is :data:`LAG_S` late."""

    def __init__(self) -> None:
        self.restored = False

    def check(self, sent_monotonic: float | None) -> None:
        """``sent_monotonic``: when the batch was handed over (``time.monotonic()``, the
        host's clock, shared by its processes); None: not known."""
        if self.restored or sent_monotonic is None:
            return
        if time.monotonic() - sent_monotonic > LAG_S:
            self.restored = True
            with contextlib.suppress(OSError, AttributeError):
                os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
