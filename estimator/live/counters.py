"""Event counters of the live runtime: the one base of its ``*Stats`` and ``*Counters``.

A counter class is a dataclass of ``int`` fields (default 0) on :class:`Counters`, which
gives it :meth:`Counters.as_dict` (the JSON of ``stats()`` and the run summary).
"""

from __future__ import annotations


class Counters:
    """Base of the counter dataclasses (:class:`estimator.live.align.AlignStats`,
    :class:`estimator.live.merge.MergeStats`, :class:`estimator.live.config.LiveCounters`)."""

    def as_dict(self) -> dict[str, int]:
        """The counters by name (a copy)."""
        return dict(self.__dict__)
