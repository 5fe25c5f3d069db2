"""Moved to :mod:`common.thrust_table`; this alias lasts until estimator/ imports from there."""

from common.thrust_table import *  # noqa: F401,F403
