"""Live estimation of mass and Izz from a pose stream and a command stream.

The live runtime in one import (``from estimator.live.runtime import ...``); each job has
its module:

- :mod:`estimator.live.core`: :class:`LiveEstimator`, the core without any network
  code (align, filter, publish), with its parts :mod:`estimator.live.history` (checkpoints,
  rewind, NIS health), :mod:`estimator.live.structure_filter`,
  :mod:`estimator.live.thrust_part` and :mod:`estimator.live.messages`;
- :mod:`estimator.live.config`: :class:`LiveConfig` and its defaults, :class:`LiveCounters`;
- :mod:`estimator.live.restart`: the ``ls-ekf`` start (batch LS on the first window in
  a background worker, :mod:`estimator.live.worker`) and the catch-up of the second filter;
- :mod:`estimator.live.align`: commands as a zero-order hold, poses released in order;
- :mod:`estimator.live.merge`: a structure's module command streams merged into its
  4N-duty command;
- :mod:`estimator.live.recorder`: :class:`LiveRecorder`, the run folder of what the
  estimator saw, written as it goes;
- :mod:`estimator.live.zenoh_run`: :func:`run_live` on a Zenoh session (:func:`keys`,
  :class:`LiveRun`, :func:`console_line`).

Estimate payload (JSON), schema ``tpods.estimate/1`` (:mod:`common.wire`)::

    {"schema": "tpods.estimate/1", "body": "tpods1", "seq": 12,
     "t": 1763770012.5,        # lab time of the last pose used, s
     "frame": 1500,            # its mocap frame number
     "t_pub": 1763770012.502,  # host time of publishing, s
     "method": "ls-ekf", "phase": "ls-ekf",   # ekf | ls-running | catching-up | ls-ekf | ls-failed
     "mass_kg": 2.27, "mass_sigma_kg": 0.01, "izz_kgm2": 0.00378, "izz_sigma_kgm2": 4e-6,
     # the sigmas are the TOTAL; their parts (root-sum-square = total):
     "mass_sigma_noise_kg": .., "mass_sigma_thrust_kg": ..,
     "izz_sigma_noise_kgm2": .., "izz_sigma_thrust_kgm2": ..,
     "state": {"x": .., "y": .., "psi": .., "u": .., "v": .., "r": ..},
     "state_sigma": {...}, "n_updates": 1499,
     "rev": 0, "revised": false}  # rev n: the n-th re-run of this pose (a late command)
"""

from __future__ import annotations

from common.wire import EST_SCHEMA, decode_estimate, encode_estimate
from estimator.live.core import (
    DEFAULT_MAX_WAIT_S,
    DEFAULT_REWIND_S,
    DIVERGED_NIS,
    LIVE_METHODS,
    NIS_WINDOW,
    LiveConfig,
    LiveCounters,
    LiveEstimator,
)
from estimator.live.recorder import LiveRecorder
from estimator.live.zenoh_run import LiveRun, console_line, keys, run_live

__all__ = [
    "DEFAULT_MAX_WAIT_S", "DEFAULT_REWIND_S", "DIVERGED_NIS", "EST_SCHEMA", "LIVE_METHODS",
    "NIS_WINDOW", "LiveConfig", "LiveCounters", "LiveEstimator", "LiveRecorder", "LiveRun",
    "console_line", "decode_estimate", "encode_estimate", "keys", "run_live",
]
