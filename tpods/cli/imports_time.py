"""The ``--time-from`` options of ``tpods import poses|commands`` (the time base itself is
:mod:`mocap_bridge.exports.run_time_base`)."""

from __future__ import annotations


def add_time_from(p, rows: str) -> None:
    """The ``--time-from`` and ``--time-from-units`` options of an import (``rows``: what
    the rows are, for the help)."""
    p.add_argument("--time-from", default=None, metavar="MAP",
                   help=f"rebuild the {rows}' times when the t= column is a nominal counter: "
                        "vx=COL,x=COL,vy=COL,y=COL,wz=COL,yaw=COL names logged finite-difference "
                        "velocities (per second) and the positions they differentiate (any of the "
                        "pairs), each row's interval is dX/VX from the best resolved one; or dt=COL, "
                        "a column of each row's interval since the previous row (unit: --time-unit). "
                        "Rows at rest take the median interval. The first row keeps its nominal time; "
                        "the map is kept in RUN/time_base.csv for the other import")
    p.add_argument("--time-from-units", default=None, metavar="LENGTH,ANGLE",
                   help="units of the --time-from positions (m|cm|mm, rad|deg; velocities per "
                        "second of the same) unless their names state them")
