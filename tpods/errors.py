"""Moved to :mod:`common.errors`; this alias lasts until estimator/ imports from there."""

from common.errors import *  # noqa: F401,F403
