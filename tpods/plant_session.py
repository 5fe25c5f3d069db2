"""The use case of ``tpods run plant``: a simulated module (or vehicle, or structure) behind
emulated valve controllers on pseudo-terminals, its poses published through the bridge
over Zenoh or sent as Vicon Tracker UDP datagrams.

- :func:`build_plant` makes the emulated controllers, the pose sink and the plant loop
  (:class:`SimulatedPlant`); nothing runs yet.
- :meth:`SimulatedPlant.serve` starts them, calls ``on_ready(lines)`` with the controllers'
  pty paths, runs until ``stop`` is set, the duration has passed or the plant fails, then
  stops everything in ``finally`` (the bridge's source finished, the session closed).
- :meth:`SimulatedPlant.write_truth` writes truth.csv and switches.csv.

Masses in kg, Izz in kg m^2, noise in m and rad, rates in Hz, times in s.
"""

from __future__ import annotations

import math
import socket
import sys
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from common.errors import UserError
from common.gcpause import frozen_heap


def udp_target(spec: str) -> tuple[str, int]:
    """``udp:HOST:PORT`` (HOST may be empty: 127.0.0.1) as a resolved (address, port), or
    one UserError naming --mocap and what is wrong, before anything starts."""
    host, sep, port_text = spec[4:].rpartition(":")
    try:
        port = int(port_text)
    except ValueError:
        port = None
    if not sep or port is None:
        raise UserError(f"--mocap must be udp:HOST:PORT, got {spec!r}")
    if not 1 <= port <= 65535:
        raise UserError(f"--mocap {spec}: port {port} is out of range (1-65535)")
    host = host or "127.0.0.1"
    try:
        addr = socket.getaddrinfo(host, port, socket.AF_INET, socket.SOCK_DGRAM)[0][4][0]
    except (socket.gaierror, UnicodeError) as exc:
        raise UserError(f"--mocap {spec}: cannot resolve host {host!r} "
                        f"({getattr(exc, 'strerror', None) or exc})") from None
    return addr, port


def parse_friction(text: str | None) -> tuple[float, float, float]:
    """``CT,CR,KB`` (N s/m, N m s/rad, N m s/m); None: no friction."""
    if not text:
        return 0.0, 0.0, 0.0
    try:
        ct, cr, kb = (float(x) for x in text.split(","))
    except ValueError:
        raise UserError(f"--friction must be CT,CR,KB, got {text!r}") from None
    return ct, cr, kb


@dataclass
class SimulatedPlant:
    """The parts :func:`build_plant` made: the plant loop, its controllers (one per module),
    the valves it reads, the pose sink's bridge (zenoh) or None (udp)."""

    plant: Any
    ctrls: list
    valves: Any
    params: Any
    body: str
    mocap: str
    structure: Any = None
    vehicle: Any = None
    session: Any = None
    source: Any = None
    bridge: Any = None
    servers: list = field(default_factory=list)

    def serve(self, stop: threading.Event, duration_s: float | None, *, pose_rate_hz: float,
              on_ready: Callable[[list[str], str], object] = lambda _p, _s: None) -> None:
        """Run until ``stop``, ``duration_s`` or a plant error (module doc). ``on_ready``
        gets the lines naming each controller's pty and the plant's summary line."""
        from bench.emulators import serve_pty
        from tpods.cli.stopping import wait_for_stop

        def stop_on_error() -> None:
            if self.plant.error is not None:
                stop.set()

        sys.setswitchinterval(2e-4)  # the emulated controller reacts within a fraction of a ms
        self.servers = [serve_pty(c) for c in self.ctrls]
        bridge_thread = None
        if self.bridge is not None:
            bridge_thread = threading.Thread(target=self.bridge.run, args=(self.source, stop),
                                             daemon=True)
        try:
            with frozen_heap():  # no long GC pause while the plant runs
                if bridge_thread is not None:
                    bridge_thread.start()
                self.plant.start()
                if self.structure is None:  # a module or a vehicle: one controller
                    paths = [f"valves: {self.servers[0].path}"]
                else:
                    paths = [f"valves {m.name}: {srv.path}"
                             for m, srv in zip(self.structure.modules, self.servers, strict=True)]
                p = self.params
                com = (f", centre of mass ({p.cx:g}, {p.cy:g}) m"
                       if self.structure or self.vehicle else "")
                on_ready(paths, f"plant: m {p.mass_kg:g} kg, Izz {p.izz_kgm2:g} kg m^2{com}, "
                                f"{pose_rate_hz:g} Hz poses of {self.body} ({self.mocap}); "
                                "Ctrl-C to stop")
                wait_for_stop(stop, duration_s, stop_on_error, every_s=0.2)
        finally:
            stop.set()
            self.plant.stop()
            for srv in self.servers:
                srv.stop()
            if self.source is not None:
                self.source.finish()
            if bridge_thread is not None:
                bridge_thread.join(timeout=5.0)
            if self.session is not None:
                self.session.close()

    def write_truth(self, folder: Path) -> None:
        """truth.csv (t_lab, the state) and switches.csv (each valve change) into ``folder``."""
        t, s = self.plant.truth_arrays()
        np.savetxt(folder / "truth.csv", np.column_stack([t, s]), delimiter=",",
                   header="t_lab,x,y,psi,u,v,r", comments="", fmt="%.12g")
        with (folder / "switches.csv").open("w") as fh:
            fh.write("t_lab," + ",".join(f"d{i + 1}" for i in range(len(self.valves.duties)))
                     + "\n")
            for ts, du in self.plant.switches:
                fh.write(f"{ts:.9f}," + ",".join(f"{x:g}" for x in du) + "\n")

    def summary(self) -> str:
        p = self.plant
        return (f"plant: {p.frames} poses ({p.occluded} occluded), {len(p.switches)} valve "
                f"changes, {sum(c.watchdog_trips for c in self.ctrls)} watchdog trip(s)")


def build_plant(*, mass_kg: float | None, izz_kgm2: float | None, clock: Any,
                thrust_table: str | None = None, friction: str | None = None,
                structure: Any = None, vehicle: Any = None, body: str | None = None,
                mocap: str = "zenoh", zenoh_options: Any = None, udp_block_size: int = 1024,
                pose_rate_hz: float = 120.0, noise_pos_m: float = 0.01,
                noise_yaw_rad: float = math.radians(1.0), occlusion: float = 0.0,
                seed: int | None = None) -> SimulatedPlant:
    """Make a simulated plant (module doc). ``mass_kg``/``izz_kgm2`` None (with a structure
    or vehicle): its [body] values, else its geometry's guess; ``zenoh_options``: the
    command's parsed Zenoh options (``mocap="zenoh"``)."""
    from bench.emulators import EmulatedValveController
    from common.thrust_table import load_thrust_table
    from estimator.plant.model import PlantParams
    from tpods.plant_loop import MocapNoise, PlantLoop, push_sink, udp_sink

    table = load_thrust_table(thrust_table)
    ct, cr, kb = parse_friction(friction)
    noise = MocapNoise(noise_pos_m, noise_yaw_rad, occlusion)
    body = body or (vehicle.name if vehicle is not None else "tpods1")
    if vehicle is not None and thrust_table is not None:
        vehicle.check_table_option()
        vehicle = vehicle.with_table(table)
    if structure is not None or vehicle is not None:
        g = (structure or vehicle).initial_guess()  # [body] values where given, else the geometry
        params = PlantParams(g["mass"] if mass_kg is None else mass_kg,
                             g["izz"] if izz_kgm2 is None else izz_kgm2, ct=ct, cr=cr, kb=kb,
                             cx=g["cx"], cy=g["cy"])
    elif mass_kg is None or izz_kgm2 is None:
        raise UserError("a simulated module needs its mass and Izz")
    else:
        params = PlantParams(mass_kg, izz_kgm2, ct=ct, cr=cr, kb=kb)
    if vehicle is not None:  # one N-channel driver
        valves = EmulatedValveController(vehicle.n_channels)
        ctrls = [valves]
    elif structure is not None:
        from tpods.plant_loop import StructureThrust, StructureValves

        ctrls = [EmulatedValveController(4) for _ in structure.modules]
        valves = StructureValves(ctrls)
        table = StructureThrust(structure)
    else:
        valves = EmulatedValveController(4)
        ctrls = [valves]
    session = source = bridge = None
    if mocap == "zenoh":
        from common.zenoh_net import open_session
        from mocap_bridge.bridge import Bridge
        from mocap_bridge.sources.push import PushSource

        session = open_session(zenoh_options)
        source = PushSource("plant")
        sink = push_sink(source, body)
        bridge = Bridge(session)
    elif mocap.startswith("udp:"):
        sink = udp_sink(udp_target(mocap), body, udp_block_size or None)
    else:
        raise UserError(f"--mocap must be zenoh or udp:HOST:PORT, got {mocap!r}")
    if vehicle is not None:  # its valve dead time and rise too
        from tpods.plant_vehicle import vehicle_plant

        plant = vehicle_plant(valves, params, vehicle, sink, clock=clock,
                              pose_rate_hz=pose_rate_hz, noise=noise, seed=seed)
    else:
        plant = PlantLoop(valves, params, table, sink, clock=clock, pose_rate_hz=pose_rate_hz,
                          noise=noise, seed=seed)
    return SimulatedPlant(plant, ctrls, valves, params, body, mocap, structure, vehicle,
                          session, source, bridge)
