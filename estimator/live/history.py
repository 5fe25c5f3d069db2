"""What the live filter keeps of its past: checkpoints to rewind to, the estimate history,
the recent NIS and the health tests on it.

After every update of the live filter (:meth:`LiveHistory._after_update`) the estimator
appends (t, m, sigma m, Izz, sigma Izz) to its ``history``, the NIS to a window of the last
:data:`NIS_WINDOW` updates, and a checkpoint ``(pose t, index in hist_t, z, P)`` kept for
``rewind_s`` lab seconds. A command that arrives after poses it governs restores the
checkpoint at or before it and re-filters the poses since (:meth:`LiveHistory._rewind`),
each re-run estimate then carries its revision number (published again when every update
is published);
the ``ls-ekf`` catch-up keeps and uses its checkpoints the same way
(:func:`checkpoint_at`, :func:`prune_checkpoints`). :attr:`LiveHistory.diverged` and
:attr:`LiveHistory.inconsistent` are the batch EKF's tests on the recent NIS.

:class:`LiveHistory` is a part of :class:`estimator.live.core.LiveEstimator` (a mixin): it
reads the estimator's filter state, pose history, ``_step`` and counters.
"""

from __future__ import annotations

import bisect
import collections
import functools
import math

import numpy as np

from common import chi2  # scipy.stats.chi2 without its import cost

DIVERGED_NIS = 10.0
"""A mean normalised innovation squared above this over the last ``NIS_WINDOW``
updates (3 expected) flags the filter as diverged, as the batch EKF does."""
NIS_WINDOW = 200
CHECKPOINT_BLOCK = 256
"""Checkpoints older than the rewind horizon are dropped in blocks of at least this many."""

Checkpoint = tuple[float, int, np.ndarray, np.ndarray]
"""(pose t, index of the pose in the estimator's ``hist_t``, z after its update, P)."""


@functools.cache
def _nis_limits() -> np.ndarray:
    """``max(4, chi2_0.999(3n) / n)`` for n = 0 .. NIS_WINDOW (index n)."""
    n = np.arange(1, NIS_WINDOW + 1)
    return np.concatenate([[np.inf], np.maximum(4.0, chi2.ppf(0.999, 3 * n) / n)])


class NisWindow(collections.deque):
    """The last ``maxlen`` NIS values with their running sum (:meth:`total`): the mean for
    every published estimate without summing the window each time."""

    def __init__(self, maxlen: int) -> None:
        super().__init__(maxlen=maxlen)
        self._sum = 0.0
        self._n = 0

    def append(self, x: float) -> None:
        if len(self) == self.maxlen:
            self._sum -= self[0]
        super().append(x)
        self._sum += x
        self._n += 1
        if self._n % self.maxlen == 0:  # no drift of the running sum
            self._sum = math.fsum(self)

    def extend(self, xs) -> None:
        for x in xs:
            self.append(x)

    def total(self) -> float:
        """The sum of the window (summed again when an infinite value spoiled the running one)."""
        if not math.isfinite(self._sum):
            self._sum = sum(self)
        return self._sum


def history_entry(t: float, z: np.ndarray, P: np.ndarray) -> tuple[float, ...]:
    """One row of the estimate history: (t, mass kg, its sigma, Izz kg m^2, its sigma)."""
    return (t, float(z[6]), math.sqrt(max(P[6, 6], 0.0)),
            float(z[7]), math.sqrt(max(P[7, 7], 0.0)))


def checkpoint_at(ck: list[Checkpoint], t: float) -> Checkpoint | None:
    """The last checkpoint at or before ``t``, the later ones dropped from ``ck``; None (and
    ``ck`` unchanged) when every checkpoint is later."""
    j = bisect.bisect_right([c[0] for c in ck], t) - 1
    if j < 0:
        return None
    del ck[j + 1:]
    return ck[j]


def prune_checkpoints(ck: list[Checkpoint], oldest_t: float) -> None:
    """Drop the checkpoints before ``oldest_t`` (the rewind horizon), in blocks."""
    if len(ck) > CHECKPOINT_BLOCK and ck[CHECKPOINT_BLOCK - 1][0] < oldest_t:
        del ck[:bisect.bisect_left([c[0] for c in ck], oldest_t)]


class LiveHistory:
    """The past of the live filter of :class:`~estimator.live.core.LiveEstimator`."""

    def _init_history(self) -> None:
        self.history: list[tuple[float, float, float, float, float]] = []
        """(t, mass, mass sigma, izz, izz sigma) after every update (for plots)."""
        self._ck: list[Checkpoint] = []
        """Checkpoints of the live filter within ``rewind_s``: (pose t, index in hist, z, P)."""
        self._rewind_t: float | None = None
        self._revs: dict[int, int] = {}
        """Index in ``hist_t`` -> how many times a rewind re-ran that pose (re-runnable ones)."""
        self._nis_recent = NisWindow(maxlen=NIS_WINDOW)
        _nis_limits()  # the chi-square limits now, not in the middle of a stream

    def _after_update(self, t: float, idx: int) -> None:
        """Bookkeeping after the live filter's update with pose ``hist_t[idx]``: history,
        NIS, checkpoint."""
        z, P = self.z, self.P
        self.history.append(history_entry(t, z, P))
        if not math.isnan(self.last_nis):
            self._nis_recent.append(self.last_nis)
        horizon = self.config.rewind_s
        if horizon > 0:
            ck = self._ck
            ck.append((t, idx, z.copy(), P.copy()))
            prune_checkpoints(ck, t - horizon)

    def _rewind(self) -> None:
        """A command arrived after poses it governs: restore the checkpoint at or before
        it and re-filter the poses since with the commands now known."""
        t_c, self._rewind_t = self._rewind_t, None
        c = checkpoint_at(self._ck, t_c)
        if c is None:  # older than every checkpoint (the aligner refuses those): nothing to do
            return
        t_prev, idx, z, P = c
        del self.history[len(self.history) - (len(self.hist_t) - 1 - idx):]
        self.z, self.P, self.t_last = z.copy(), P.copy(), t_prev
        n = 0
        each = self.config.publish_rate_hz == 0
        revs = self._revs
        for i in range(idx + 1, len(self.hist_t)):
            t = self.hist_t[i]
            self.z, self.P, self.last_nis = self._step(self.z, self.P, self.t_last, t,
                                                       self.hist_pose[i], k=i)
            self.t_last = t
            self.frame_last = self.hist_frame[i]
            self.rev_last = revs[i] = revs.get(i, 0) + 1
            self._after_update(t, i)
            if each:  # every estimate is published: each re-run one again, marked revised
                self._publish(self._last_pub)
            n += 1
        if len(revs) > 16 * CHECKPOINT_BLOCK and self._ck:  # only poses still re-runnable
            oldest = self._ck[0][1]
            for i in [i for i in revs if i < oldest]:
                del revs[i]
        self.counters.rewinds += 1
        self.counters.rewind_updates += n

    @property
    def diverged(self) -> bool:
        """Non-physical or non-finite mass or Izz, a covariance that broke down, or a mean
        NIS over the last updates above :data:`DIVERGED_NIS` (the batch EKF's test)."""
        if self.z is None:
            return False
        z, P = self.z, self.P
        if not (z[6] > 0 and z[7] > 0 and np.all(np.isfinite(z))):
            return True
        if not (P[6, 6] > 0 and P[7, 7] > 0 and np.all(np.isfinite(P))):
            return True
        return self._nis_recent_mean() > DIVERGED_NIS

    def _nis_recent_mean(self) -> float:
        nis = self._nis_recent
        return nis.total() / len(nis) if len(nis) >= min(NIS_WINDOW, 20) else math.nan

    @property
    def inconsistent(self) -> bool:
        """The recent innovations are larger than the covariance allows (mean NIS over the
        last updates above ``max(4, chi2_0.999(3n) / n)``, the batch EKF's test): the
        reported sigma is not to be trusted, though the filter has not diverged."""
        mean = self._nis_recent_mean()
        if not math.isfinite(mean):
            return False
        return bool(mean > _nis_limits()[len(self._nis_recent)])
