"""Moved to :mod:`common.runfolder`; this alias lasts until estimator/ imports from there."""

from common.runfolder import *  # noqa: F401,F403
from common.runfolder import _json_default  # noqa: F401  (estimator.cli_batch)
