"""Timed playback, the simulation source and the push source for live producers.

- :class:`Playback`: frames with times on their own timeline, re-published on the
  host clock at ``rate_scale`` times real time (0 = as fast as possible). Used by
  replay and by the simulation source.
- :class:`SimSource`: poses of the foundation's plant simulator (a run folder's
  commands and truth re-simulated, or the nominal phase-sine run).
- :class:`PushSource`: a bounded queue a live producer (e.g. a plant-in-the-loop
  simulation) pushes samples into, in real time or faster; the bridge publishes them.
"""

from __future__ import annotations

import math
import queue
import threading
import time
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from common.errors import UserError
from mocap_bridge.pose import PoseSample, yaw_quat

# one body in one frame: body, x, y, z (m), qx, qy, qz, qw, occluded
BodyPose = tuple[str, float, float, float, float, float, float, float, bool]


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
        wall0 = time.time()
        mono0 = time.monotonic()
        scale = self.rate_scale
        for fr in self.frames:
            if stop.is_set():
                return
            if scale:
                offset = (fr.t_src - t0) / scale
                while True:
                    wait = mono0 + offset - time.monotonic()
                    if wait <= 0:
                        break
                    if stop.wait(min(wait, 0.2)):
                        return
                t_recv = time.time()
                t = wall0 + offset
            else:
                t = t_recv = time.time()
            self.counters["frames"] += 1
            yield [PoseSample(b, fr.frame, t, t_recv, x, y, z, qx, qy, qz, qw, occ, fr.t_src)
                   for (b, x, y, z, qx, qy, qz, qw, occ) in fr.poses]

    def close(self) -> None:
        pass


class SimSource(Playback):
    """Poses of the plant simulator, played on the host clock.

    :meth:`from_run` re-simulates a simulated run folder (its commands, its truth from
    run.json and its measurement settings, same seed: the poses equal its poses.csv);
    with no folder, the nominal 120 s phase-sine run of the paper.
    """

    @classmethod
    def from_run(cls, run_dir: Path | None, rate_scale: float = 1.0, body: str = "tpods1",
                 seed: int | None = None) -> SimSource:
        from estimator.model import PlantParams
        from estimator.sim import SimConfig, simulate

        if run_dir is None:
            from estimator.inputs import phase_sine

            cmd_t, duty = phase_sine(120.0, 50.0)
            res = simulate(cmd_t, duty, PlantParams(2.268, 3.78e-3),
                           config=SimConfig(seed=0 if seed is None else seed))
            name = "sim:phase-sine"
        else:
            from common.runfolder import read_run

            run = read_run(run_dir)
            truth = run.truth
            if not truth:
                raise UserError(f"{run_dir}: run.json holds no simulation truth; "
                                "use --source replay:{run_dir} to replay its poses")
            st = run.meta.get("settings", {})
            try:
                params = PlantParams(float(truth["mass_kg"]), float(truth["izz_kgm2"]),
                                     float(truth.get("arm_m", 0.05)),
                                     *(float(truth.get(k, 0.0)) for k in ("ct", "cr", "kb", "ax", "ay")))
                cfg = SimConfig(pose_rate_hz=float(st.get("pose_rate_hz", 120.0)),
                                noise_pos_m=float(st.get("noise_pos_m", 0.01)),
                                noise_yaw_rad=float(st.get("noise_yaw_rad", math.radians(1.0))),
                                drop=float(st.get("drop", 0.0)),
                                seed=st.get("seed", 0) if seed is None else seed,
                                initial_state=tuple(truth.get("initial_state", (0.0,) * 6)),
                                clamp=bool(st.get("clamp", False)))
            except (KeyError, TypeError, ValueError) as exc:
                raise UserError(f"{run_dir / 'run.json'}: bad truth or settings ({exc})") from None
            if run.duty_pct is not None and run.thrust_n is None:
                res = simulate(run.cmd_t, run.duty_pct, params, config=cfg)
            else:
                t_cmd, thrust = run.thrust_profile()
                res = simulate(t_cmd, np.zeros((len(t_cmd), 4)), params, config=cfg, thrust_n=thrust)
            name = f"sim:{run_dir}"
        nominal = np.rint((res.pose_t - res.cmd_t[0]) * res.config.pose_rate_hz).astype(np.int64) + 1
        src = cls(name, frames_from_planar(body, res.pose_t, res.pose, nominal), rate_scale)
        src.result = res
        return src


class PushSource:
    """A queue that live producers push poses into; the bridge publishes them in order.

    Thread-safe. ``push`` blocks when ``maxsize`` samples are waiting (back-pressure on
    a producer running faster than the bridge). ``finish()`` ends the stream after the
    queued samples. Samples are taken as already in the table frame unless
    ``in_table_frame=False``.
    """

    _END = object()

    def __init__(self, name: str = "push", maxsize: int = 10000, in_table_frame: bool = True) -> None:
        self.name = name
        self.in_table_frame = in_table_frame
        self.counters = {"pushed": 0}
        self._q: queue.Queue = queue.Queue(maxsize)
        self._frames: dict[str, int] = {}

    def push(self, sample: PoseSample, timeout: float | None = None) -> None:
        """Queue one sample (raises ``queue.Full`` after ``timeout`` seconds)."""
        self._q.put(sample, timeout=timeout)
        self.counters["pushed"] += 1

    def push_pose(self, body: str, frame: int, t: float, x: float, y: float, z: float,
                  quat: tuple[float, float, float, float], occluded: bool = False,
                  t_src: float | None = None, t_recv: float | None = None) -> None:
        """Queue a 3-D pose: metres, quaternion ``(qx, qy, qz, qw)``, host time ``t`` (s)."""
        self.push(PoseSample(body, int(frame), t, time.time() if t_recv is None else t_recv,
                             x, y, z, *quat, occluded, t_src))

    def push_planar(self, body: str, t: float, x: float, y: float, psi: float,
                    frame: int | None = None, t_src: float | None = None,
                    occluded: bool = False) -> None:
        """Queue a planar pose (m, rad); frame numbers count up per body when not given."""
        if frame is None:
            frame = self._frames.get(body, 0) + 1
        self._frames[body] = frame
        self.push_pose(body, frame, t, x, y, 0.0, yaw_quat(psi), occluded, t_src)

    def finish(self) -> None:
        """End the stream once the queued samples are published."""
        self._q.put(self._END)

    def batches(self, stop: threading.Event) -> Iterator[list[PoseSample]]:
        q = self._q
        while not stop.is_set():
            try:
                item = q.get(timeout=0.2)
            except queue.Empty:
                continue
            batch = []
            while True:
                if item is self._END:
                    if batch:
                        yield batch
                    return
                batch.append(item)
                if len(batch) >= 256:
                    break
                try:
                    item = q.get_nowait()
                except queue.Empty:
                    break
            yield batch

    def close(self) -> None:
        pass
