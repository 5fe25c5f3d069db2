"""TPODS lab-bench toolkit: the application floor (the ``tpods`` command line, the lab-day
orchestration: demo, valve player, plant-in-the-loop module)."""

from common import __version__

__all__ = ["__version__"]
