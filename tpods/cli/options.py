"""Argument adders shared by the commands: each adds an option family that means the same
wherever it appears (same names, defaults, types and help), so that it is written once.

- :func:`add_result_out`: ``--out DIR|FILE.json`` and ``--force`` of a command whose
  result is one JSON file, with more beside it in a folder (:func:`common.outputs.result_output`).
- :func:`add_report_out`: the required report folder of the ``tpods report`` commands.
- :func:`add_key_prefixes` and :func:`check_key_prefixes`: the Zenoh key prefixes of the
  commands that read or write the live streams (``view``, ``export mcap``, ``estimate live``).
- :func:`add_structure_or_vehicle`: ``--structure F`` or ``--vehicle FILE`` (one of them),
  both into ``args.structure`` (a vehicle goes wherever a structure goes).
- :func:`add_noise_sigmas`: the pose noise of a fit (``estimate batch|crlb``,
  ``calibrate thrust``).
- single options written alike by several commands: the valve controller's
  (:func:`add_duty_limits`, :func:`add_watchdog_ms`), a simulated run's (:func:`add_input_choice`,
  :func:`add_sine_amplitude`, :func:`add_sim_duration`, :func:`add_cmd_rate`,
  :func:`add_pose_rate`, :func:`add_thrust_table`, :func:`add_random_seed`,
  :func:`add_noise_seed`) and the console's (:func:`add_json_flag`, :func:`add_quiet`,
  :func:`add_no_progress`).

The Zenoh connection options are :func:`common.zenoh_net.add_zenoh_options`; ``--force``
alone is :func:`common.outputs.add_force`. Nothing here imports a heavy library
(docs/architecture.md, "Lazy imports").
"""

from __future__ import annotations

import argparse

from common.argtypes import (
    SIGMA_POS_M,
    SIGMA_YAW_DEG,
    nonneg_float,
    positive_float,
    random_seed,
    vehicle_file,
)
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


VEHICLE_HELP = ("vehicle.toml: any planar vehicle, its thrusters as data; read as a "
                "structure is (commands.csv t,d1..dN in its thruster order)")


def add_structure_or_vehicle(p: argparse.ArgumentParser | argparse._ArgumentGroup,
                             structure_help: str, vehicle_help: str = VEHICLE_HELP) -> None:
    """``--structure F`` and ``--vehicle FILE``, mutually exclusive, both stored in
    ``args.structure`` (``--vehicle`` as a :class:`common.argtypes.VehicleFile`, which
    :func:`common.vehicle.load_layout` reads as a vehicle)."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--structure", default=None, metavar="F", help=structure_help)
    g.add_argument("--vehicle", dest="structure", type=vehicle_file, default=None,
                   metavar="FILE", help=vehicle_help)


def add_noise_sigmas(p: argparse.ArgumentParser) -> None:
    """``--sigma-pos`` (m) and ``--sigma-yaw-deg``: the pose noise a fit assumes."""
    p.add_argument("--sigma-pos", type=SIGMA_POS_M, default=0.01,
                   help="position noise sigma, m (default 0.01)")
    p.add_argument("--sigma-yaw-deg", type=SIGMA_YAW_DEG, default=1.0,
                   help="yaw noise sigma, deg (default 1)")


def add_duty_limits(p: argparse.ArgumentParser) -> None:
    """``--duty-limits LOW,HIGH`` (%, default 10,90) the valve controller allows; None when
    not given (a vehicle's default is its own range: :func:`tpods.play_session.plan_play`)."""
    p.add_argument("--duty-limits", default=None,
                   help="allowed duty of an open valve, LOW,HIGH %% (default 10,90)")


def add_watchdog_ms(p: argparse.ArgumentParser) -> None:
    """``--watchdog-ms`` (default 500) of the valve controller."""
    p.add_argument("--watchdog-ms", type=int, default=500, help="controller watchdog, ms (default 500)")


def add_no_progress(p: argparse.ArgumentParser) -> None:
    """``--no-progress``: no progress bar."""
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def add_random_seed(p: argparse.ArgumentParser) -> None:
    """``--seed`` (default 0) of a random draw."""
    p.add_argument("--seed", type=random_seed, default=0, help="random seed (default 0)")


def add_sim_duration(p: argparse.ArgumentParser) -> None:
    """``--duration`` (s, default 120) of a simulated run."""
    p.add_argument("--duration", type=positive_float, default=120.0, help="seconds (default 120)")


def add_cmd_rate(p: argparse.ArgumentParser) -> None:
    """``--cmd-rate`` (Hz, default 50) of a generated input."""
    p.add_argument("--cmd-rate", type=positive_float, default=50.0, help="Hz (default 50)")


def add_pose_rate(p: argparse.ArgumentParser) -> None:
    """``--pose-rate`` (Hz, default 120) of simulated poses."""
    p.add_argument("--pose-rate", type=positive_float, default=120.0, help="Hz (default 120)")


def add_thrust_table(p: argparse.ArgumentParser) -> None:
    """``--thrust-table F``: the thrust table TOML (default the paper's Table 2)."""
    p.add_argument("--thrust-table", default=None, metavar="F",
                   help="thrust table TOML (default: the paper's Table 2)")


def add_json_flag(p: argparse.ArgumentParser) -> None:
    """``--json``: print exactly one JSON object on stdout."""
    p.add_argument("--json", action="store_true", help="print exactly one JSON object on stdout")


def add_input_choice(p: argparse.ArgumentParser) -> None:
    """``--input``: phase-sine, translate-rotate, pulses or a commands.csv."""
    p.add_argument("--input", default="phase-sine",
                   help="phase-sine, translate-rotate, pulses (each valve fully open in turn, "
                        "for on/off valves) or PATH/commands.csv (default phase-sine)")


def add_sine_amplitude(p: argparse.ArgumentParser) -> None:
    """``--amplitude`` (duty %, default 20) of the phase-sine input."""
    p.add_argument("--amplitude", type=nonneg_float, default=20.0,
                   help="phase-sine amplitude, duty percent (default 20)")


def add_noise_seed(p: argparse.ArgumentParser) -> None:
    """``--seed`` (default 0) of the simulated noise."""
    p.add_argument("--seed", type=random_seed, default=0, help="noise seed (default 0)")


def add_quiet(p: argparse.ArgumentParser) -> None:
    """``--quiet``: no console line."""
    p.add_argument("--quiet", action="store_true", help="no console line")
