"""Replay a run folder (poses.csv) or a bridge log (samples.csv) on the host clock.

Accepted folders, first match wins:

- ``DIR/samples.csv``: one body's full samples as the recorder writes them;
- ``DIR/*/samples.csv``: a recording of several bodies (one sub-folder each);
- ``DIR/poses.csv``: a run folder (``t,x,y,psi``), body name from ``--body`` or the
  folder name; z = 0, orientation a pure yaw.

Samples are re-published at ``rate_scale`` times real time (0 = as fast as possible)
with ``t_src`` holding the original run time so a recorder writes the same times.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from common.errors import UserError
from common.runfolder import POSE_COLUMNS, read_table
from common.wire import sanitize_chunk
from mocap_bridge.sources.playback import Frame, Playback, frames_from_planar

if TYPE_CHECKING:
    import pandas as pd

SAMPLE_COLUMNS = ("body", "frame", "t", "t_recv", "t_src", "x", "y", "z", "qx", "qy", "qz",
                  "qw", "yaw", "occluded", "t_rx")


def read_samples(path: Path) -> pd.DataFrame:
    """Read a recorder ``samples.csv``; refuses a bad file with one line."""
    import pandas as pd  # lazy: `tpods mocap bridge` with another source starts without it
    try:
        df = pd.read_csv(path, keep_default_na=True)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise UserError(f"{path}: not a readable samples file ({str(exc).splitlines()[0]})") from None
    missing = [c for c in ("body", "frame", "t", "x", "y", "z", "qx", "qy", "qz", "qw", "occluded")
               if c not in df.columns]
    if missing:
        raise UserError(f"{path}: missing column(s) {', '.join(missing)}")
    if len(df) == 0:
        raise UserError(f"{path}: no data rows")
    return df


def _frames_from_samples(dfs: list[pd.DataFrame], path: Path) -> list[Frame]:
    import pandas as pd
    df = pd.concat(dfs, ignore_index=True)
    t = pd.to_numeric(df["t"], errors="coerce").to_numpy(float)
    t_src = (pd.to_numeric(df["t_src"], errors="coerce").to_numpy(float)
             if "t_src" in df.columns else np.full(len(df), np.nan))
    if np.all(np.isfinite(t_src)):
        timeline = t_src
    else:
        if not np.all(np.isfinite(t)):
            raise UserError(f"{path}: column t holds a value that is not a number")
        timeline = t - np.nanmin(t)
    frame = pd.to_numeric(df["frame"], errors="coerce").to_numpy(float)
    if not np.all(np.isfinite(frame)):
        raise UserError(f"{path}: column frame holds a value that is not a number")
    occ = df["occluded"].astype(str).str.strip().str.lower().isin(("true", "1"))
    vals = df[["x", "y", "z", "qx", "qy", "qz", "qw"]].apply(pd.to_numeric, errors="coerce").to_numpy(float)
    occ = occ.to_numpy() | ~np.all(np.isfinite(vals), axis=1)
    order = np.lexsort((frame, timeline))
    frames: list[Frame] = []
    bodies = df["body"].astype(str).tolist()
    for i in order.tolist():
        key = (timeline[i], int(frame[i]))
        pose = (bodies[i], *vals[i].tolist(), bool(occ[i]))
        if frames and (frames[-1].t_src, frames[-1].frame) == key:
            frames[-1].poses.append(pose)
        else:
            frames.append(Frame(key[0], key[1], [pose]))
    return frames


class ReplaySource(Playback):
    """Replay a run folder or a bridge recording (see the module docstring)."""

    def __init__(self, path: Path, rate_scale: float = 1.0, body: str | None = None) -> None:
        path = Path(path)
        if not path.is_dir():
            raise UserError(f"{path}: replay folder not found")
        if (path / "samples.csv").is_file():
            frames = _frames_from_samples([read_samples(path / "samples.csv")], path)
        elif subs := sorted(path.glob("*/samples.csv")):
            frames = _frames_from_samples([read_samples(p) for p in subs], path)
        elif (path / "poses.csv").is_file():
            pv = read_table(path / "poses.csv", POSE_COLUMNS)
            name = body or sanitize_chunk(path.resolve().name)
            frames = frames_from_planar(name, pv[:, 0], pv[:, 1:])
        else:
            raise UserError(f"{path}: neither a run folder (poses.csv) nor a recording (samples.csv)")
        super().__init__(f"replay:{path}", frames, rate_scale)

