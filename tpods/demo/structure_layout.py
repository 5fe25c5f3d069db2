"""The structure of ``tpods demo --structure`` (see :mod:`tpods.demo.structure`): its
tracked body's name, its two modules, the truss parts with their TRUE values, the tape's
sigma, and what the structure file and the figure are made from (read by the stages and by
the report, :mod:`tpods.demo.structure_report`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

BODY = "truss"
"""The tracked body's name (its mocap key ``tpods/mocap/truss/pose``) = the structure's name."""

MODULES = (("tpods1", (-0.2, 0.0), 0.0), ("tpods2", (0.2, 0.05), 90.0))
"""(name, centre in the tracked frame [m], yaw [deg]) of the two modules."""

TRUSS_PARTS = (
    {"name": "truss bar", "mass_kg": 0.30, "shape": "rod", "length_m": 0.50,
     "position_m": (0.05, 0.0), "outline_m": (0.50, 0.02)},
    {"name": "payload", "mass_kg": 0.50, "shape": "box", "size_m": (0.08, 0.08),
     "position_m": (0.12, -0.06), "outline_m": (0.08, 0.08)},
)
"""The structure's other parts, TRUE values: the estimators' geometric start (two paper
modules, no truss) is 0.8 kg light and its centre of mass is 1-2 cm off."""

POSITION_SIGMA_M = 0.002
"""A part's position taped on the truss, 1 sigma per axis, m."""


def module_toml(with_body: dict[str, Any] | None = None) -> dict[str, Any]:
    """The structure file's content: the modules (what the estimators know), with a
    ``[body]`` when given (the simulation's truth)."""
    d: dict[str, Any] = {"name": BODY, "modules": [
        {"name": n, "position_m": list(p), "yaw_deg": y} for n, p, y in MODULES]}
    if with_body is not None:
        d["body"] = with_body
    return d


def outlines() -> list[np.ndarray]:
    """(4, 2) rectangles of the truss parts in the tracked frame, m (for the figure)."""
    out = []
    for p in TRUSS_PARTS:
        (w, h), (x, y) = p["outline_m"], p["position_m"]
        out.append(np.array([[x - w / 2, y - h / 2], [x + w / 2, y - h / 2],
                             [x + w / 2, y + h / 2], [x - w / 2, y + h / 2]]))
    return out


def shape_keys(p: dict[str, Any]) -> dict[str, Any]:
    """A truss part's shape keys as ``calibrate combine`` reads them (tuples as lists)."""
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in p.items()
            if k in ("shape", "length_m", "size_m")}
