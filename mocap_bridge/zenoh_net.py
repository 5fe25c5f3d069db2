"""Moved to :mod:`common.zenoh_net`; this alias lasts until estimator/ imports from there."""

from common.zenoh_net import *  # noqa: F401,F403
