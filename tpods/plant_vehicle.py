"""Plant in the loop for a vehicle: one emulated N-channel valve driver, the
vehicle's thrusters as the plant's virtual thrusts, its valve dead time and rise.

:class:`LayoutThrust` maps a row of duties to the virtual thrusts of a structure or vehicle
(the plant's "thrust table"; :class:`tpods.plant_loop.StructureThrust` is the same).
:class:`TimedPlantLoop` is a :class:`tpods.plant_loop.PlantLoop` whose input passes through
the vehicle's ``[valves]``: every valve change acts ``delay_s`` later and rises with time
constant ``rise_s``. It keeps every change it heard and integrates each pose interval
under :func:`estimator.live.valve_segments.timed_hold` of them -- the input the batch fit
and the live filter take for the same commands (exact means of the rise over the pieces
of the interval).
"""

from __future__ import annotations

import bisect
from collections.abc import Sequence

import numpy as np

from common.valve_timing import CUTOFF_TAU
from estimator.live.valve_segments import has_timing, timed_hold
from estimator.plant.model import PlantParams, integrate_zoh
from tpods.plant_loop import PlantLoop, Sink, StructureThrust

LayoutThrust = StructureThrust
"""Duties (..., N) to the virtual thrusts (..., 4) of a structure or a vehicle."""


class TimedPlantLoop(PlantLoop):
    """A :class:`~tpods.plant_loop.PlantLoop` of a vehicle whose valves have a dead time or
    a rise (see the module doc); the other arguments as the base class's."""

    def __init__(self, valves, params: PlantParams, vehicle, sink: Sink, **kw) -> None:
        self.vehicle = vehicle
        self._raw_t: list[float] = []
        self._raw_d: list[tuple[float, ...]] = []
        super().__init__(valves, params, LayoutThrust(vehicle), sink, **kw)

    def start(self) -> TimedPlantLoop:
        super().start()
        with self._lock:  # the duties in force when the plant starts (valves closed)
            if not self._raw_t or self._raw_t[0] > self.t_begin:
                self._raw_t.insert(0, self.t_begin)
                self._raw_d.insert(0, tuple(self.valves.duties))
        return self

    def _on_duties(self, t_emulator: float, duties: tuple[float, ...]) -> None:
        super()._on_duties(t_emulator, duties)
        with self._lock:
            t, d = self.switches[-1]
            self._switch_t.clear()  # the base class's own hold: unused here
            self._switch_thrust.clear()
            if self._raw_t and t <= self._raw_t[-1]:  # same instant: the later row wins
                self._raw_d[-1] = d
            else:
                self._raw_t.append(t)
                self._raw_d.append(d)

    def _advance(self, t_to: float) -> np.ndarray:
        """Integrate to ``t_to`` under the timed input of the changes heard so far."""
        t0 = self._t_state
        if t_to > t0:
            v = self.vehicle.valves
            with self._lock:  # from the change in force a look-back before t0 (timed_hold)
                i = max(bisect.bisect_right(self._raw_t, t0 - v.delay_s - CUTOFF_TAU * v.rise_s)
                        - 1, 0)
                n = bisect.bisect_right(self._raw_t, t_to)
                raw_t: Sequence[float] = self._raw_t[i:n]
                raw_d: Sequence[tuple[float, ...]] = self._raw_d[i:n]
            ht, hv = timed_hold(self.vehicle, raw_t, raw_d, t0, t_to)
            self._state = integrate_zoh(self._state, ht, hv, np.array([t0, t_to]),
                                        self.params)[-1]
            self._t_state = t_to
        return self._state


def vehicle_plant(valves, params: PlantParams, vehicle, sink: Sink, **kw) -> PlantLoop:
    """The plant of ``vehicle`` following ``valves`` (one N-channel controller): a
    :class:`TimedPlantLoop` when its valves have a dead time or rise, else a plain
    :class:`~tpods.plant_loop.PlantLoop` of its virtual thrusts."""
    if has_timing(vehicle):
        return TimedPlantLoop(valves, params, vehicle, sink, **kw)
    return PlantLoop(valves, params, LayoutThrust(vehicle), sink, **kw)
