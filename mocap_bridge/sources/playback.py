"""Timed playback: frames with times on their own timeline, re-published on the host
clock at ``rate_scale`` times real time (0 = as fast as possible). Used by the replay
source and by the plant simulator's source (:mod:`tpods.sim_source`); :class:`Pacer`, the
waiting, by the pcap source too.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Iterator, Sequence

import numpy as np

from common.errors import UserError
from mocap_bridge.pose import PoseSample, yaw_quat

# one body in one frame: body, x, y, z (m), qx, qy, qz, qw, occluded
BodyPose = tuple[str, float, float, float, float, float, float, float, bool]


class Pacer:
    """Items on a source timeline released on the host clock at ``rate_scale`` times real
    time (0: at once), counted from the moment the pacer is made (the first item)."""

    def __init__(self, rate_scale: float) -> None:
        self.rate_scale = rate_scale
        self.wall0, self.mono0 = time.time(), time.monotonic()

    def due(self, t_rel_s: float, stop: threading.Event) -> tuple[float, float] | None:
        """Wait until the item ``t_rel_s`` source seconds after the first is due; its
        (receive, nominal) host times, or None when ``stop`` is set while waiting."""
        if not self.rate_scale:
            now = time.time()
            return now, now
        offset = t_rel_s / self.rate_scale
        while (wait := self.mono0 + offset - time.monotonic()) > 0:
            if stop.wait(min(wait, 0.2)):
                return None
        return time.time(), self.wall0 + offset


class Frame:
    """One mocap frame on the source timeline: ``t_src`` (s), frame number, body poses."""

    __slots__ = ("t_src", "frame", "poses")

    def __init__(self, t_src: float, frame: int, poses: Sequence[BodyPose]) -> None:
        self.t_src = float(t_src)
        self.frame = int(frame)
        self.poses = poses


def frames_from_planar(body: str, t: np.ndarray, xy_psi: np.ndarray,
                       frame_no: np.ndarray | None = None) -> list[Frame]:
    """Frames of one body from planar poses ``(N,)`` times and ``(N, 3)`` x, y (m), psi (rad).

    Frame numbers default to ``round((t - t0) * rate)`` with the rate from the median
    interval (so dropped frames show up as gaps), or to 1..N when times are irregular.
    """
    t = np.asarray(t, float)
    if frame_no is None:
        frame_no = frame_numbers(t)
    out = []
    for ti, fi, (x, y, psi) in zip(t.tolist(), frame_no.tolist(), np.asarray(xy_psi, float).tolist(),
                                   strict=True):
        qx, qy, qz, qw = yaw_quat(psi)
        out.append(Frame(ti, fi, [(body, x, y, 0.0, qx, qy, qz, qw, False)]))
    return out


def frame_numbers(t: np.ndarray) -> np.ndarray:
    """Frame numbers for times ``t`` (see :func:`frames_from_planar`)."""
    t = np.asarray(t, float)
    if len(t) > 1:
        dt = float(np.median(np.diff(t)))
        if dt > 0:
            f = np.rint((t - t[0]) / dt).astype(np.int64)
            if np.all(np.diff(f) > 0) and np.allclose(f * dt, t - t[0], atol=0.25 * dt):
                return f + 1
    return np.arange(1, len(t) + 1, dtype=np.int64)


class Playback:
    """Re-publish frames on the host clock.

    ``t`` of each sample is ``start + (t_src - t_src0) / rate_scale`` on the host clock
    (the nominal capture time), ``t_recv`` the actual emission time and ``t_src`` the
    original time. ``rate_scale`` 0 means as fast as possible (then ``t = t_recv``).
    """

    in_table_frame = True

    def __init__(self, name: str, frames: list[Frame], rate_scale: float = 1.0) -> None:
        if rate_scale < 0 or not math.isfinite(rate_scale):
            raise UserError(f"rate scale must be >= 0, got {rate_scale:g}")
        if not frames:
            raise UserError(f"{name}: nothing to play")
        self.name = name
        self.frames = frames
        self.rate_scale = rate_scale
        self.counters = {"frames": 0}

    @property
    def duration_s(self) -> float:
        """Play time at this rate scale, s (0 when unpaced)."""
        if not self.rate_scale:
            return 0.0
        return (self.frames[-1].t_src - self.frames[0].t_src) / self.rate_scale

    def batches(self, stop: threading.Event) -> Iterator[list[PoseSample]]:
        t0 = self.frames[0].t_src
        pacer = Pacer(self.rate_scale)
        for fr in self.frames:
            if stop.is_set():
                return
            times = pacer.due(fr.t_src - t0, stop)
            if times is None:
                return
            t_recv, t = times
            self.counters["frames"] += 1
            yield [PoseSample(b, fr.frame, t, t_recv, x, y, z, qx, qy, qz, qw, occ, fr.t_src)
                   for (b, x, y, z, qx, qy, qz, qw, occ) in fr.poses]

    def close(self) -> None:
        pass
