"""The use case of ``tpods sim``: :func:`simulate_case` simulates the planar plant under
held thruster commands (a generated input or a commands.csv), for one module or a
structure/vehicle file, and returns a :class:`SimCase` that writes the run folder
(commands.csv, poses.csv, truth.csv, run.json, the structure.toml) and says what it holds.

Units: s, Hz, kg, kg m^2, m, duty %; the pose noise in m and rad. Prints nothing (the
size announcement of :mod:`estimator.plant.size_checks` aside); a user's error raises
:class:`common.errors.UserError` naming the ``tpods sim`` options.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from common.constants import PAPER_IZZ_KGM2, PAPER_MASS_KG
from common.errors import UserError


@dataclass
class SimCase:
    """A simulated run: ``result`` (:class:`estimator.plant.sim.SimResult`), the
    ``structure`` simulated (or None), its centre of mass ``com`` (m, tracked frame),
    the ``input_name`` and ``table_name`` as given, ``warnings`` (text lines)."""

    result: Any
    structure: Any
    com: tuple[float, float]
    input_name: str
    table_name: str
    warnings: list[str] = field(default_factory=list)

    def write(self, folder: Path) -> None:
        """The run folder's files into ``folder`` (a structure's structure.toml too)."""
        from estimator.plant.sim import write_sim_run

        write_sim_run(self.result, folder, self.input_name, self.table_name)
        if self.structure is not None:
            write_sim_structure(folder, self.structure)

    def lines(self) -> list[str]:
        """The summary printed under ``wrote <folder>``."""
        from estimator.plant.sim import summary_lines

        out = ["  " + line for line in summary_lines(self.result)]
        s = self.structure
        if s is not None:
            cx, cy = self.com
            out.append(f"  {s.kind:<9}       {s.name}: {s.parts_text()}, centre of mass "
                       f"({cx:+.4g}, {cy:+.4g}) m in the tracked frame")
            out += ["  " + line for line in body_note(s)]
        return out


def simulate_case(input_name: str = "phase-sine", *, duration_s: float | None = None,
                  mass_kg: float | None = None, izz_kgm2: float | None = None,
                  structure: str | Path | None = None, com: Sequence[float] | None = None,
                  friction: Sequence[float] | None = None, tilt: Sequence[float] | None = None,
                  thrust_table: str | Path | None = None, clamp: bool = False,
                  pose_rate_hz: float = 120.0, cmd_rate_hz: float = 50.0,
                  amplitude_pct: float = 20.0, omega_rad_s: float = 1.0,
                  noise_pos_m: float = 0.01, noise_yaw_deg: float = 1.0, drop: float = 0.0,
                  seed: int = 0, warn: Callable[[str], None] | None = None) -> SimCase:
    """Simulate ``input_name`` (phase-sine, translate-rotate, pulses or a commands.csv)
    for ``duration_s`` (default 120 s; a commands.csv: its length); the plant's mass and
    Izz default to the structure's [body], else the paper's module; ``friction``
    (ct, cr, kb), ``tilt`` (ax, ay, m/s^2) default to none. ``warn`` receives each
    warning as it arises (they are in the result's ``warnings`` too)."""
    from common.thrust_table import load_thrust_table
    from estimator.plant.inputs import DEFAULT_DURATION_S, INPUT_NAMES, make_input
    from estimator.plant.model import PlantParams
    from estimator.plant.sim import SimConfig, simulate
    from estimator.plant.size_checks import check_sim_size

    warnings: list[str] = []
    table = load_thrust_table(thrust_table)
    s = _structure(structure, thrust_table, table)
    generated = input_name in INPUT_NAMES
    if generated:  # sizes and duties from the options, before anything is allocated
        check_sim_size(duration_s or DEFAULT_DURATION_S, pose_rate_hz, cmd_rate_hz,
                       duration_given=bool(duration_s), input_name=input_name)
        for t in ([table] if s is None else s.tables()):
            w = check_phase_sine(input_name, amplitude_pct, omega_rad_s, cmd_rate_hz,
                                 t.duty_range, clamp)
            warnings += w
            for line in w if warn is not None else ():
                warn(line)
    cmd_t, duty = make_input(input_name, duration_s, cmd_rate_hz, amplitude_pct, omega_rad_s,
                             n_channels=4 if s is None else s.n_channels)
    if not generated:
        check_sim_size(float(cmd_t[-1] - cmd_t[0]), pose_rate_hz, cmd_rate_hz, n_cmds=len(cmd_t),
                       duration_given=bool(duration_s), input_name=input_name)
    ct, cr, kb = friction or (0.0, 0.0, 0.0)
    ax, ay = tilt or (0.0, 0.0)
    body = s.body if s is not None else None
    if getattr(s, "kind", None) == "vehicle" and not s.is_single_at_origin and (
            (mass_kg is None and body.mass_kg is None) or (izz_kgm2 is None and body.izz_kgm2 is None)):
        raise UserError(f"{s.source}: states no [body] mass_kg and izz_kgm2: give --mass "
                        "and --izz (the paper's 2.3 kg module is not this vehicle)")
    mass = mass_kg or (body and body.mass_kg) or PAPER_MASS_KG
    izz = izz_kgm2 or (body and body.izz_kgm2) or PAPER_IZZ_KGM2
    if com is not None and s is None:
        raise UserError("--com is a structure's centre of mass: give --structure F too")
    cx, cy = com or (body and body.com_m) or (0.0, 0.0)
    params = PlantParams(mass, izz, ct=ct, cr=cr, kb=kb, ax=ax, ay=ay,
                         **({"cx": cx, "cy": cy} if (cx, cy) != (0.0, 0.0) else {}))
    cfg = SimConfig(pose_rate_hz=pose_rate_hz, noise_pos_m=noise_pos_m,
                    noise_yaw_rad=math.radians(noise_yaw_deg), drop=drop, seed=seed, clamp=clamp)
    try:
        thrust_t, virtual = (None, None) if s is None else s.input_profile(cmd_t, duty, clamp=clamp)
        res = simulate(cmd_t, duty, params, table, cfg, thrust_n=virtual, thrust_t=thrust_t)
    except UserError as exc:  # a duty of a commands.csv outside the table: name the options
        raise UserError(f"--input {input_name}: {clamp_named(exc)}") from None
    return SimCase(res, s, (cx, cy), input_name, str(thrust_table or "built-in Table 2"), warnings)


def _structure(path: str | Path | None, thrust_table, table):
    """The structure file ``path`` with ``table`` applied to the modules without their
    own (when ``thrust_table`` is given), or None."""
    from common.layout_files import load_layout

    if path is None:
        return None
    s = load_layout(path)
    if thrust_table is not None:
        s.check_table_option()
        s = s.with_table(table)
    return s


def body_note(structure) -> list[str]:
    """What ``tpods estimate`` will make of the [body] values of the structure.toml copied
    into a simulated run (the copy is the user's file as given; the truth is in run.json)."""
    known, priors = structure.body.known(), structure.body.priors()
    if not known and not priors:
        return []
    parts = []
    if known:
        parts.append("fixes " + ", ".join(f"{n} = {v:g}" for n, v in known.items()) + " (known)")
    if priors:
        parts.append("takes a prior on " + ", ".join(priors))
    return [f"[body]          tpods estimate {' and '.join(parts)} from the run's structure.toml; "
            "to estimate them, give the truth with --mass/--izz/--com and leave them out of "
            "[body]"]


def write_sim_structure(folder: Path, structure) -> None:
    """Make a simulated run folder a structure run: its structure.toml (self-contained)
    and the structure named in run.json."""
    from common.runwriter import write_json_atomic
    from common.vehicle import Vehicle

    structure.write(folder)
    meta_file = folder / "run.json"
    meta = json.loads(meta_file.read_text())
    if isinstance(structure, Vehicle):
        meta["settings"]["vehicle"] = {"name": structure.name, "thrusters": structure.describe()}
    else:
        meta["settings"]["structure"] = {"name": structure.name, "modules": structure.describe()}
    write_json_atomic(meta_file, meta)


def clamp_named(exc: Exception) -> str:
    """A thrust table's duty error with the option to give (``--clamp``) named."""
    return str(exc).replace("(use the clamp option to saturate)", "(add --clamp to saturate)")


def check_phase_sine(input_name: str, amplitude_pct: float, omega_rad_s: float,
                     cmd_rate_hz: float, duty_range: tuple[float, float], clamp: bool) -> list[str]:
    """The phase-sine's duties 50 +/- ``amplitude_pct`` against 0..100 % and the thrust
    table's valid ``duty_range`` (unless ``clamp``): a UserError; ``omega_rad_s`` above the
    Nyquist frequency of ``cmd_rate_hz``: the warning returned."""
    if input_name != "phase-sine":
        return []
    a, (lo, hi) = amplitude_pct, duty_range
    a_max = min(50.0 - lo, hi - 50.0)
    d_lo, d_hi = 50.0 - a, 50.0 + a
    if d_lo < 0 or d_hi > 100:
        raise UserError(f"--amplitude {a:g} puts the phase-sine duties at {d_lo:g}..{d_hi:g} %, "
                        f"outside 0..100 %; the thrust table's valid range {lo:g}-{hi:g} % allows "
                        f"--amplitude {max(a_max, 0):g} or less")
    if a > 0 and (d_lo < lo or d_hi > hi) and not clamp:
        raise UserError(f"--amplitude {a:g} puts the phase-sine duties at {d_lo:g}..{d_hi:g} %, "
                        f"outside the thrust table's valid range {lo:g}-{hi:g} %: use --amplitude "
                        f"{max(a_max, 0):g} or less, or add --clamp to saturate")
    nyquist = math.pi * cmd_rate_hz
    if omega_rad_s > nyquist:
        return [f"--omega {omega_rad_s:g} rad/s is above the Nyquist frequency of --cmd-rate "
                f"{cmd_rate_hz:g} Hz ({nyquist:.4g} rad/s): the held commands alias to a slower sine"]
    return []
