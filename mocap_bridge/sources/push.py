"""The push source: a bounded queue a live producer (e.g. a plant-in-the-loop
simulation) pushes samples into, in real time or faster; the bridge publishes them."""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Iterator

from mocap_bridge.pose import PoseSample, yaw_quat


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
