"""Pose exports and command logs as other labs' software writes them, read into arrays.

Pure parsing on text (no files opened, no CLI): :func:`read_poses` reads a Vicon Tracker
or Nexus CSV export (:mod:`.vicon_csv`), an OptiTrack Motive CSV export
(:mod:`.motive_csv`) or any CSV through a column map (:mod:`.generic_csv`), detected by
:mod:`.detect`, into a :class:`~mocap_bridge.exports.table.PoseTable` (planar poses in
s, m, rad with the counts of what was skipped). :mod:`.command_log` reads valve states
(vectors, bitmasks, per-valve columns) and force/torque columns. ``tpods import`` writes
them as a run folder (docs/run-format.md, "Importing recordings from other labs").
"""

from mocap_bridge.exports.detect import PoseOptions, detect_format, read_poses
from mocap_bridge.exports.table import FloorPlane, PoseTable

__all__ = ["FloorPlane", "PoseOptions", "PoseTable", "detect_format", "read_poses"]
