"""Emulated bench devices served on pseudo-terminals (no hardware needed).

- :class:`bench.emulators.valves.EmulatedValveController`: protocol v1 valve board.
- :class:`bench.emulators.scout.EmulatedScout`: OHAUS Scout balance weighing the
  thrust of one nozzle of a linked valve emulator.
- :func:`bench.emulators.pty.serve_pty`: put any emulator on a pty, giving a device
  path the real pyserial driver opens.
"""

from bench.emulators.pty import PtyServer, serve_pty
from bench.emulators.scout import EmulatedScout
from bench.emulators.valves import EmulatedValveController

__all__ = ["EmulatedScout", "EmulatedValveController", "PtyServer", "serve_pty"]
