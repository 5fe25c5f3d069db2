"""Argument adders shared by the commands: each adds an option family that means the same
wherever it appears (same names, defaults, types and help), so that it is written once.

- :func:`add_result_out`: ``--out DIR|FILE.json`` and ``--force`` of a command whose
  result is one JSON file, with more beside it in a folder (:func:`common.outputs.result_output`).
- :func:`add_report_out`: the required report folder of the ``tpods report`` commands.
- :func:`add_key_prefixes` and :func:`check_key_prefixes`: the Zenoh key prefixes of the
  commands that read or write the live streams (``view``, ``export mcap``, ``estimate live``).
- :func:`add_noise_sigmas`: the pose noise of a fit (``estimate batch|crlb``,
  ``calibrate thrust``).

The Zenoh connection options are :func:`common.zenoh_net.add_zenoh_options`; ``--force``
alone is :func:`common.outputs.add_force`. Nothing here imports a heavy library
(docs/architecture.md, "Lazy imports").
"""

from __future__ import annotations

import argparse

from common.argtypes import SIGMA_POS_M, SIGMA_YAW_DEG
from common.errors import UserError
from common.outputs import add_force


def add_result_out(p: argparse.ArgumentParser, folder_files: str, only: str) -> None:
    """``--out DIR|FILE.json`` (default: nothing written) and ``--force``: the folder DIR
    receives ``folder_files``, a FILE.json only ``the {only}``."""
    p.add_argument("--out", default=None, metavar="DIR|FILE.json",
                   help=f"write {folder_files} in folder DIR, or only the {only} to FILE.json")
    add_force(p)


def add_report_out(p: argparse.ArgumentParser) -> None:
    """``--out DIR`` (required: the report folder) and ``--force``."""
    p.add_argument("--out", required=True, metavar="DIR", help="report folder")
    add_force(p)


def add_key_prefixes(p: argparse.ArgumentParser, keys: str = "command/estimate") -> None:
    """``--prefix`` (the ``keys``: ``<prefix>/<body>/cmd``, ...) and ``--mocap-prefix``
    (poses: ``<mocap-prefix>/<body>/pose``)."""
    p.add_argument("--prefix", default="tpods", help=f"{keys} key prefix (default tpods)")
    p.add_argument("--mocap-prefix", default="tpods/mocap",
                   help="pose key prefix (default tpods/mocap)")


def check_key_prefixes(args: argparse.Namespace) -> None:
    """Refuse an empty ``--prefix`` or ``--mocap-prefix`` (a key cannot start with '/')."""
    for opt, v in (("--prefix", args.prefix), ("--mocap-prefix", args.mocap_prefix)):
        if not v.strip("/"):
            raise UserError(f"{opt} must not be empty")


def add_noise_sigmas(p: argparse.ArgumentParser) -> None:
    """``--sigma-pos`` (m) and ``--sigma-yaw-deg``: the pose noise a fit assumes."""
    p.add_argument("--sigma-pos", type=SIGMA_POS_M, default=0.01,
                   help="position noise sigma, m (default 0.01)")
    p.add_argument("--sigma-yaw-deg", type=SIGMA_YAW_DEG, default=1.0,
                   help="yaw noise sigma, deg (default 1)")
