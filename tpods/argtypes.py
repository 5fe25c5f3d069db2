"""Moved to :mod:`common.argtypes`; this alias lasts until estimator/ imports from there."""

from common.argtypes import *  # noqa: F401,F403
