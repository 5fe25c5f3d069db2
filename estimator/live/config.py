"""Settings and counters of the live estimator: :class:`LiveConfig`, its defaults,
:class:`LiveCounters`.

The methods (``ekf``, ``ls-ekf``), how long a pose waits for a late command, how far back a
late command still corrects the filter, the publish rate, the LS window and the catch-up's
budget; the checks of a user's values (``tpods: error: ...``); what the estimator counts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from common.errors import UserError
from estimator.filters.config import PAPER, EkfConfig
from estimator.live.counters import Counters

LIVE_METHODS = ("ekf", "ls-ekf")
DEFAULT_MAX_WAIT_S = 0.0
"""Default bound on how long a pose waits for a late command (host seconds, counted from
the earlier of its capture and arrival times): none. The filter updates on each pose as it
arrives with the commands it has; a command stamped before poses already filtered makes it
re-run them from the state saved before the command (``DEFAULT_REWIND_S``), and the
estimates it re-ran are published again, marked revised. A wait only delays every estimate
by up to its length to spare a few of those re-runs."""
DEFAULT_REWIND_S = 2.0
"""How far back (lab seconds) a command arriving after the poses it governs still
corrects the live filter: it restores the state saved before the command and re-filters
the poses since (``LiveConfig.rewind_s``; 0 turns this off)."""


@dataclass(frozen=True)
class LiveConfig:
    """Settings of the live estimator (SI units; host seconds for waits and rates)."""

    method: str = "ekf"
    ekf: EkfConfig = PAPER
    ls_window_s: float = 20.0
    ls_start: str = "reuse"
    max_wait_s: float = DEFAULT_MAX_WAIT_S
    publish_rate_hz: float = 10.0
    catchup_budget_s: float = 0.0002
    """Host seconds of ``ls-ekf`` catch-up per pass of the loop: a pose that arrives meanwhile
    waits at most this long."""
    ls_in_process: bool = False
    n_channels: int = 4
    rewind_s: float = DEFAULT_REWIND_S
    clock_offset_s: float = 0.0
    """The mocap host's clock minus the player host's (s), taken off every pose time."""
    clock_offset_auto: bool = False
    """Apply the measured offset once it has settled (:mod:`estimator.live.clock_apply`);
    the command line's default (``--clock-offset-ms auto``)."""

    def __post_init__(self) -> None:
        if self.method not in LIVE_METHODS:
            raise UserError(f"method must be one of {', '.join(LIVE_METHODS)}")
        if self.ls_start not in ("reuse", "handoff"):
            raise UserError("ls_start must be reuse or handoff")
        if not (self.max_wait_s >= 0 and math.isfinite(self.max_wait_s)):
            raise UserError("the alignment wait must be a non-negative number of seconds")
        if not (self.publish_rate_hz >= 0 and math.isfinite(self.publish_rate_hz)):
            raise UserError("the publish rate must be >= 0 Hz (0: every update)")
        if self.ls_window_s <= 0:
            raise UserError("the LS window must be positive")
        if not math.isfinite(self.clock_offset_s) or abs(self.clock_offset_s) > 10.0:
            raise UserError("the clock offset must be a number of ms within +-10000")
        if not (self.rewind_s >= 0 and math.isfinite(self.rewind_s)):
            raise UserError("the rewind horizon must be a non-negative number of seconds")


@dataclass
class LiveCounters(Counters):
    """What the live estimator counted (``LiveEstimator.stats()``)."""

    poses_rx: int = 0
    cmds_rx: int = 0
    malformed: int = 0
    other_body: int = 0
    updates: int = 0
    estimates_published: int = 0
    publish_errors: int = 0
    catchup_updates: int = 0
    max_backlog: int = 0
    max_queue: int = 0
    rewinds: int = 0
    rewind_updates: int = 0
    revised_published: int = 0
    """Estimates published again after a rewind re-ran their pose (``revised``)."""
    cmds_no_change: int = 0
    """Commands that repeat the duty in force at their time (holds): they never rewind."""
    before_ls: int = 0
    motion_resets: int = 0
