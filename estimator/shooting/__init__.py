"""Whole runs fitted by multiple shooting: segments with their own initial states, shared
physical parameters, a segment-clustered sigma and thruster health (:mod:`.fit`,
:mod:`.health`)."""
