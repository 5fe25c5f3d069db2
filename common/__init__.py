"""The ground floor of the toolkit: what every other package may import.

Errors the CLI prints as one line (``errors``), argument types (``argtypes``), run
folders (``runfolder``), thrust tables (``thrust_table``), the wire formats of the
Zenoh streams (``wire``), the Zenoh session helpers (``zenoh_net``) and named
constants (``constants``). Nothing here imports from another package of the toolkit.
"""

__version__ = "0.1.0"
