"""The Foxglove layout of ``tpods view`` (docs/foxglove/tpods_layout.json).

Written in the layout format that Foxglove's *Layouts -> Import from file* reads (and its
open-source fork Lichtblick): ``configById`` (panel id -> settings), ``layout`` (a mosaic
tree of splits), ``globalVariables``, ``userNodes``. The topics are those of
:func:`tpods.viewer.topics_for`; ``tpods view --write-layout FILE --body NAME ...`` writes
one for other bodies (pure data: this module does not load the SDK).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from common.wire import sanitize_chunk

COLORS = ("#4e98e2", "#f5774d", "#f7df71", "#61cbff", "#a395e2", "#6f3be8", "#eb5757", "#27ae60")
SHIPPED_BODY = "tpods1"


def _topic(body: str, kind: str) -> str:  # = tpods.viewer.topics_for (without the SDK)
    return f"/tpods/{sanitize_chunk(body)}/{kind}"


def _series(path: str, label: str, color: str, *, dashed: bool = False,
            step: bool = False) -> dict[str, Any]:
    s: dict[str, Any] = {"value": path, "enabled": True, "timestampMethod": "receiveTime",
                         "label": label, "color": color}
    if dashed:
        s["lineStyle"] = "dashed"
    if step:
        s["lineInterpolation"] = "step"
    return s


def _plot(title: str, paths: list[dict[str, Any]], y_label: str) -> dict[str, Any]:
    return {"foxglovePanelTitle": title, "paths": paths, "showLegend": True,
            "legendDisplay": "floating", "showPlotValuesInLegend": True, "isSynced": True,
            "xAxisVal": "timestamp", "timeWindowMode": "automatic", "yAxisLabel": y_label,
            "showXAxisLabels": True, "showYAxisLabels": True, "sidebarDimension": 240}


def _column(ids: list[str]) -> Any:
    """Panels stacked top to bottom, equal heights."""
    if len(ids) == 1:
        return ids[0]
    return {"first": ids[0], "second": _column(ids[1:]), "direction": "column",
            "splitPercentage": 100.0 / len(ids)}


def layout(bodies: list[str] | tuple[str, ...] = (SHIPPED_BODY,)) -> dict[str, Any]:
    """The layout for these bodies: a top-down 3D view of their frames on the table; mass and
    Izz with their 1-sigma bands (total) and the noise and thrust parts of sigma; duties; yaw;
    NIS and the estimator's phase and status; the raw health message."""
    bodies = [sanitize_chunk(b) for b in bodies] or [SHIPPED_BODY]
    cfg: dict[str, Any] = {}
    cfg["3D!table"] = {
        "foxglovePanelTitle": "table (top view)", "followTf": "table", "followMode": "follow-none",
        "cameraState": {"perspective": False, "distance": 4.0, "phi": 0.0, "thetaOffset": 0.0,
                        "target": [0, 0, 0], "targetOffset": [0, 0, 0],
                        "targetOrientation": [0, 0, 0, 1], "fovy": 45, "near": 0.01, "far": 100},
        "scene": {"enableStats": False, "transforms": {"showLabel": True, "axisScale": 2.0}},
        "transforms": {f"frame:{b}": {"visible": True} for b in bodies},
        "topics": {_topic(b, "frame"): {"visible": True} for b in bodies},
        "layers": {"grid": {"visible": True, "frameLocked": True, "label": "grid (0.25 m)",
                            "instanceId": "grid", "layerId": "foxglove.Grid", "frameId": "table",
                            "size": 4, "divisions": 16, "lineWidth": 1, "color": "#248eff80",
                            "position": [0, 0, 0], "rotation": [0, 0, 0], "order": 1}},
    }
    mass, izz, sig, duty, yaw, nis = [], [], [], [], [], []
    multi = len(bodies) > 1
    for i, b in enumerate(bodies):
        c = COLORS[i % len(COLORS)]
        tag = f"{b} " if multi else ""
        est, h = _topic(b, "estimate"), _topic(b, "health")
        mass += [_series(f"{est}.mass_kg", f"{tag}mass", c),
                 _series(f"{est}.mass_hi_kg", f"{tag}+1 sigma", c, dashed=True),
                 _series(f"{est}.mass_lo_kg", f"{tag}-1 sigma", c, dashed=True)]
        izz += [_series(f"{est}.izz_kgm2", f"{tag}Izz", c),
                _series(f"{est}.izz_hi_kgm2", f"{tag}+1 sigma", c, dashed=True),
                _series(f"{est}.izz_lo_kgm2", f"{tag}-1 sigma", c, dashed=True)]
        sig += [_series(f"{est}.mass_sigma_kg", f"{tag}total", COLORS[0] if not multi else c),
                _series(f"{est}.mass_sigma_noise_kg", f"{tag}noise", COLORS[1] if not multi else c,
                        dashed=True),
                _series(f"{est}.mass_sigma_thrust_kg", f"{tag}thrust",
                        COLORS[2] if not multi else c, dashed=True)]
        duty += [_series(f"{_topic(b, 'duty')}.d{k}", f"{tag}d{k}",
                         COLORS[(k - 1 + 4 * i) % len(COLORS)], step=True) for k in range(1, 5)]
        yaw.append(_series(f"{_topic(b, 'pose')}.yaw_deg", f"{tag}yaw", c))
        nis.append(_series(f"{h}.nis", f"{tag}NIS (3 expected)", c))
    cfg["Plot!mass"] = _plot("mass (kg), estimate +/- 1 sigma (total)", mass, "kg")
    cfg["Plot!izz"] = _plot("Izz (kg m^2), estimate +/- 1 sigma (total)", izz, "kg m^2")
    cfg["Plot!sigma"] = _plot("sigma of mass (kg): total, noise, thrust table", sig, "kg")
    cfg["Plot!duty"] = _plot("valve duties (%)", duty, "%")
    cfg["Plot!yaw"] = _plot("yaw (deg)", yaw, "deg")
    cfg["Plot!nis"] = _plot("NIS", nis, "NIS")
    cfg["StateTransitions!health"] = {
        "foxglovePanelTitle": "estimator phase and status", "isSynced": True,
        "paths": [p for b in bodies for p in (
            {"value": f"{_topic(b, 'health')}.phase", "timestampMethod": "receiveTime",
             "label": f"{b} phase"},
            {"value": f"{_topic(b, 'health')}.status", "timestampMethod": "receiveTime",
             "label": f"{b} status"})]}
    cfg["RawMessages!health"] = {"foxglovePanelTitle": "health (last message)",
                                 "topicPath": _topic(bodies[0], "health"), "diffEnabled": False,
                                 "diffMethod": "custom", "diffTopicPath": "",
                                 "showFullMessageForDiff": False, "expansion": "all"}
    cfg["RawMessages!clock"] = {"foxglovePanelTitle": "run clock (lab time of the last pose)",
                                "topicPath": "/tpods/clock", "diffEnabled": False,
                                "diffMethod": "custom", "diffTopicPath": "",
                                "showFullMessageForDiff": False, "expansion": "all"}
    left = {"first": "3D!table", "second": _column(["RawMessages!clock", "RawMessages!health"]),
            "direction": "column", "splitPercentage": 60}
    middle = _column(["Plot!mass", "Plot!izz", "Plot!sigma"])
    right = _column(["Plot!duty", "Plot!yaw", "Plot!nis", "StateTransitions!health"])
    return {
        "configById": cfg,
        "globalVariables": {},
        "userNodes": {},
        "playbackConfig": {"speed": 1},
        "layout": {"first": left, "second": {"first": middle, "second": right, "direction": "row"},
                   "direction": "row", "splitPercentage": 30},
    }


def layout_json(bodies: list[str] | tuple[str, ...] = (SHIPPED_BODY,)) -> str:
    """:func:`layout` as the text of a layout file."""
    return json.dumps(layout(bodies), indent=2) + "\n"


def write_layout(path: str | Path, bodies: list[str] | tuple[str, ...] | None = None,
                 force: bool = False) -> Path:
    """Write the layout for ``bodies`` (default the shipped body) to the .json file
    ``path`` (an existing one only with ``force``); returns the path."""
    from common.errors import UserError

    path = Path(path)
    if path.suffix != ".json":
        raise UserError(f"--write-layout {path}: a Foxglove layout is a .json file")
    if path.exists() and not force:
        raise UserError(f"{path} already exists; add --force to replace it or choose another name")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(layout_json(bodies or [SHIPPED_BODY]))
    except OSError as exc:
        raise UserError(f"cannot write {path} ({exc.strerror})") from None
    return path


def topics_in(doc: dict[str, Any]) -> set[str]:
    """Every topic a layout refers to (for the tests: all must be served)."""
    out: set[str] = set()

    def path_topic(p: str) -> str:
        return p.split(".", 1)[0]

    for conf in doc["configById"].values():
        for s in conf.get("paths", []):
            out.add(path_topic(s["value"]))
        if "topicPath" in conf:
            out.add(path_topic(conf["topicPath"]))
        out.update(conf.get("topics", {}))
    return out
