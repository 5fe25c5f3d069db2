"""Emulated bench devices served on pseudo-terminals (no hardware needed).

- :class:`bench.emulators.valves.EmulatedValveController`: protocol v1 valve board.
- :class:`bench.emulators.scout.EmulatedScout`: OHAUS Scout balance weighing the
  thrust of one nozzle of a linked valve emulator.
- :func:`bench.emulators.pty.serve_pty`: put any emulator on a pty, giving a device
  path the real pyserial driver opens; :func:`bench.emulators.tcp.serve_tcp` on a
  loopback TCP port (``socket://127.0.0.1:PORT``, like a module's Wi-Fi bridge).
- :mod:`bench.emulators.pair`: the two linked as ``tpods bench emulate`` serves them, and
  their logs.
"""

from bench.emulators.pty import PtyServer, serve_pty
from bench.emulators.scout import EmulatedScout
from bench.emulators.tcp import TcpServer, serve_tcp
from bench.emulators.valves import EmulatedValveController

__all__ = ["EmulatedScout", "EmulatedValveController", "PtyServer", "TcpServer", "serve_pty",
           "serve_tcp"]
