"""Plant in the loop: a simulated TPODS module driven by an emulated valve controller.

:class:`PlantLoop` listens to the duty changes of a
:class:`bench.emulators.valves.EmulatedValveController` (whoever drives it: the input
player over a pty, a test), integrates the plant model exactly under the held
thrusts (:func:`estimator.plant.model.integrate_zoh`, split at every switch) with a chosen
truth (mass, Izz, optional friction and tilt; thrust from a *truth* thrust table) and
emits a pose every ``1 / pose_rate_hz`` lab seconds with mocap-like noise, on the lab
clock (real time or faster, :class:`tpods.clock.LabClock`). Where the poses go is a
*sink*: :func:`push_sink` (the bridge's :class:`mocap_bridge.sources.push.PushSource`,
published over Zenoh) or :func:`udp_sink` (Vicon Tracker datagrams for a
``tpods mocap bridge --source vicon-udp`` process). The true states at the pose times
and the switch times are kept for the report (:meth:`PlantLoop.truth_arrays`).
"""

from __future__ import annotations

import math
import socket
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from bench.emulators import EmulatedValveController, serve_pty
from estimator.plant.model import PlantParams, integrate_zoh
from estimator.plant.output import tracked_pose
from mocap_bridge.bridge import Bridge
from mocap_bridge.sources.push import PushSource
from mocap_bridge.sources.vicon_udp import build_datagram
from tpods.clock import LabClock

Sink = Callable[[int, float, float, float, float, bool], None]
"""``sink(frame, t_lab, x_m, y_m, psi_rad, occluded)``."""


def push_sink(source, body: str = "tpods1") -> Sink:
    """Sink pushing planar poses into a bridge PushSource (capture time = lab time)."""
    def sink(frame: int, t: float, x: float, y: float, psi: float, occluded: bool) -> None:
        source.push_planar(body, t, x, y, psi, frame=frame, occluded=occluded)
    return sink


def udp_sink(address: tuple[str, int], body: str = "tpods1",
             block_size: int | None = 1024) -> Sink:
    """Sink sending Vicon Tracker UDP datagrams (mm, Euler XYZ) to ``address``.

    Each datagram is padded with zeros to ``block_size`` bytes as Tracker pads to its
    "Data Block Size" (256, 512 or 1024; None sends the bare items). The bridge stamps
    these with its receive time: use it at time scale 1 only.
    """
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)

    def sink(frame: int, t: float, x: float, y: float, psi: float, occluded: bool) -> None:
        vals = (math.nan,) * 6 if occluded else (x * 1e3, y * 1e3, 0.0, 0.0, 0.0, psi)
        try:
            sock.sendto(build_datagram(frame, [(0, body, vals)], block_size), address)
        except OSError:  # nobody listening: a mocap keeps streaming anyway
            pass
    sink.close = sock.close  # type: ignore[attr-defined]
    return sink


@dataclass(frozen=True)
class MocapNoise:
    """Measurement model: Gaussian noise (m, rad) and random occlusions (probability)."""

    pos_m: float = 0.01
    yaw_rad: float = math.radians(1.0)
    occlusion_prob: float = 0.0


class PlantLoop:
    """Simulated module following an emulated valve controller.

    Args:
        valves: the emulated controller (its listener reports every duty change).
        params: true plant (mass, Izz, arm, friction, tilt).
        table: truth thrust table (duty percent to newtons); open duties outside its
            range are clamped, as a real valve would still blow.
        sink: where poses go (see :func:`push_sink`, :func:`udp_sink`).
        clock: the lab clock (shared with the player for time scales > 1).
        pose_rate_hz: mocap frame rate in lab Hz.
        noise: measurement noise and occlusions.
        seed: random seed of the noise.
        initial_state: (6,) x, y, psi, u, v, r at the start.
    """

    def __init__(self, valves, params: PlantParams, table, sink: Sink, *,
                 clock: LabClock | None = None, pose_rate_hz: float = 120.0,
                 noise: MocapNoise | None = None, seed: int | None = 0,
                 initial_state=(0.0,) * 6) -> None:
        if pose_rate_hz <= 0:
            raise ValueError("pose rate must be positive")
        self.valves = valves
        self.params = params
        self.table = table
        self.sink = sink
        self.clock = clock or LabClock()
        self.pose_rate_hz = float(pose_rate_hz)
        self.noise = noise or MocapNoise()
        self.rng = np.random.default_rng(seed)
        self._state = np.asarray(initial_state, float).copy()
        self._lock = threading.Lock()
        self._switch_t: list[float] = []
        self._switch_thrust: list[np.ndarray] = []
        self.switches: list[tuple[float, tuple[float, ...]]] = []
        """Every duty change seen: (lab time, duties %)."""
        self._thrust = self._thrust_of(valves.duties)
        self._t_state = -math.inf
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.t_begin: float | None = None
        self.frames = 0
        self.occluded = 0
        self.max_behind_s = 0.0
        self._truth_t: list[float] = []
        self._truth_s: list[np.ndarray] = []
        self.error: BaseException | None = None
        valves.add_listener(self._on_duties)

    def _thrust_of(self, duties) -> np.ndarray:
        return self.table.thrust_n(np.asarray([duties], float), clamp=True)[0]

    def _on_duties(self, t_emulator: float, duties: tuple[float, ...]) -> None:
        # the emulator's own (monotonic) time of the command: the moment its bytes were read
        age = time.monotonic() - t_emulator
        with self._lock:  # appended under the lock: no pose is integrated past it unseen
            t = self.clock.now()
            if 0.0 <= age < 1.0:
                t -= age * self.clock.scale
            t = max(t, self._t_state)
            thrust = self._thrust_of(duties)
            self._switch_t.append(t)
            self._switch_thrust.append(thrust)
            self.switches.append((t, tuple(duties)))

    # ------------------------------------------------------------- running
    def start(self) -> PlantLoop:
        self.t_begin = self.clock.now()
        self._t_state = self.t_begin
        self._thread = threading.Thread(target=self._run, name="plant-loop", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)

    def __enter__(self) -> PlantLoop:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def _advance(self, t_to: float) -> np.ndarray:
        """Integrate from the last state time to ``t_to`` under the switches seen so far."""
        with self._lock:
            sw_t = [t for t in self._switch_t if t <= t_to]
            n = len(sw_t)
            sw_f = self._switch_thrust[:n]
            del self._switch_t[:n]
            del self._switch_thrust[:n]
        t0 = self._t_state
        cmd_t = [t0] + [max(t, t0) for t in sw_t]
        thrust = np.vstack([self._thrust] + sw_f) if sw_f else self._thrust[None, :]
        if sw_f:
            self._thrust = sw_f[-1]
        if t_to > t0:
            s = integrate_zoh(self._state, np.asarray(cmd_t), thrust, np.array([t0, t_to]),
                              self.params)[-1]
            self._state = s
            self._t_state = t_to
        return self._state

    def _run(self) -> None:
        try:
            k = 0
            dt = 1.0 / self.pose_rate_hz
            nz = self.noise
            while not self._stop.is_set():
                tk = self.t_begin + k * dt
                if not self.clock.sleep_until(tk, self._stop):
                    return
                self.max_behind_s = max(self.max_behind_s, self.clock.now() - tk)
                s = self._advance(tk)
                self._truth_t.append(tk)
                self._truth_s.append(s.copy())
                k += 1
                occ = nz.occlusion_prob > 0 and self.rng.random() < nz.occlusion_prob
                # mocap tracks its frame, not the centre of mass (a structure)
                p0 = tracked_pose(s, self.params.cx, self.params.cy) if self.params.com_offset else s
                x = p0[0] + (self.rng.normal(0.0, nz.pos_m) if nz.pos_m > 0 else 0.0)
                y = p0[1] + (self.rng.normal(0.0, nz.pos_m) if nz.pos_m > 0 else 0.0)
                psi = p0[2] + (self.rng.normal(0.0, nz.yaw_rad) if nz.yaw_rad > 0 else 0.0)
                psi = math.remainder(psi, 2.0 * math.pi)
                self.frames += 1
                self.occluded += occ
                self.sink(k, tk, x, y, psi, occ)
        except BaseException as exc:  # surfaced to the owner through .error
            self.error = exc

    # -------------------------------------------------------------- truth
    def truth_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """(N,) lab times and (N, 6) true states at every emitted pose (yaw continuous)."""
        n = len(self._truth_t)
        return (np.asarray(self._truth_t[:n], float),
                np.asarray(self._truth_s[:n], float).reshape(-1, 6))


class StructureValves:
    """Several emulated controllers seen as one (a structure): ``duties`` is every
    module's duties in the structure's channel order, and a listener hears every change of
    any of them with the whole row."""

    def __init__(self, controllers: list) -> None:
        self.controllers = list(controllers)

    @property
    def duties(self) -> tuple[float, ...]:
        return tuple(x for c in self.controllers for x in c.duties)

    def add_listener(self, callback: Callable[[float, tuple[float, ...]], None]) -> None:
        for j, c in enumerate(self.controllers):
            def on_change(t: float, new: tuple[float, ...], j: int = j) -> None:
                # called before controller j switches: compose the row with its new duties
                row = [x for k, other in enumerate(self.controllers)
                       for x in (new if k == j else other.duties)]
                callback(t, tuple(row))
            c.add_listener(on_change)


class StructureThrust:
    """A structure as the plant's thrust table: duties of every channel (..., 4N) to the
    virtual thrusts (..., 4) of :meth:`common.structure.Structure.virtual_thrust`."""

    def __init__(self, structure) -> None:
        self.structure = structure

    def thrust_n(self, duty_pct, clamp: bool = False) -> np.ndarray:
        return self.structure.virtual_thrust(np.asarray(duty_pct, float), clamp=clamp)


class SimulatedModule:
    """A whole simulated module on the lab side: an emulated valve controller served on a
    pty (``valves_path``, what the player opens), a :class:`PlantLoop` following it, and a
    bridge publishing its poses over ``session`` (``<prefix>/<body>/pose``).

    Use as a context manager; ``plant.truth_arrays()`` and ``valves.log`` hold the truth.
    """

    def __init__(self, session, params: PlantParams, table, *, clock: LabClock | None = None,
                 body: str = "tpods1", pose_rate_hz: float = 120.0, noise: MocapNoise | None = None,
                 seed: int | None = 0, prefix: str = "tpods/mocap", n_channels: int = 4,
                 switch_interval_s: float | None = 2e-4) -> None:
        self.valves = EmulatedValveController(n_channels)
        self.source = PushSource(f"plant:{body}")
        self.bridge = Bridge(session, prefix=prefix)
        self.plant = PlantLoop(self.valves, params, table, push_sink(self.source, body),
                               clock=clock, pose_rate_hz=pose_rate_hz, noise=noise, seed=seed)
        self._stop = threading.Event()
        self._bridge_thread = threading.Thread(target=self.bridge.run, args=(self.source, self._stop),
                                               name="module-bridge", daemon=True)
        self.server = None
        self.valves_path: str | None = None
        self.switch_interval_s = switch_interval_s
        self._old_switch = 0.005

    def start(self) -> SimulatedModule:
        # a short GIL switch interval: the emulated controller answers (and stamps) a command
        # within a fraction of a millisecond even while the plant and bridge threads compute
        # (with the default 5 ms, valve switches jitter by milliseconds: a bias on Izz)
        self._old_switch = sys.getswitchinterval()
        if self.switch_interval_s is not None:
            sys.setswitchinterval(self.switch_interval_s)
        self.server = serve_pty(self.valves)
        self.valves_path = self.server.path
        self._bridge_thread.start()
        self.plant.start()
        return self

    def stop(self) -> None:
        self.plant.stop()
        self.source.finish()
        self._bridge_thread.join(timeout=5.0)
        self._stop.set()
        self._bridge_thread.join(timeout=5.0)
        if self.server is not None:
            self.server.stop()
        if self.switch_interval_s is not None:
            sys.setswitchinterval(self._old_switch)

    def __enter__(self) -> SimulatedModule:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
