"""Rigid structures moved by several TPODS modules: ``structure.toml``.

A structure is one rigid body whose pose motion capture reports (the *tracked frame*,
origin O, axes xs/ys) carrying N modules. Module m sits at ``position_m`` (its centre, m,
in the tracked frame) with its x axis turned ``yaw_deg`` (counter-clockwise seen from
above) from xs; its four thrusters have the paper's geometry about the module centre
(docs/run-format.md, "Thruster geometry"). Each module has its own thrust table and its
own valve block: the per-nozzle thrust of module m uses module m's table with ``k`` = the
number of open valves OF THAT MODULE (each module has its own accumulator).

The file (docs/run-format.md, "Structure runs")::

    name = "truss"
    [[modules]]
    name = "tpods1"
    position_m = [-0.25, 0.0]
    yaw_deg = 0.0
    thrust_table = "tpods1_table.toml"   # optional, relative to this file; default Table 2
    mass_kg = 0.72                       # optional, known module mass
    izz_kgm2 = 1.2e-3                    # optional, known module Izz (about its centre)
    [[modules]]
    name = "sat"
    position_m = [0.4, 0.0]
    vehicle = "sat.toml"                 # optional: a vehicle.toml whose
                                         # thrusters this module carries (its own tables)
    ...
    [body]                               # optional: known values or priors of the whole
    mass_kg = 1.9                        # body; a value with a sigma is a prior
    mass_sigma_kg = 0.01
    izz_kgm2 = 0.05
    izz_sigma_kgm2 = 0.005
    com_m = [0.03, 0.0]                  # centre of mass in the tracked frame, m
    com_sigma_m = 0.01                   # one number, or [sx, sy]

The plant (:mod:`estimator.plant.model`) takes the thrusts of ONE module at the tracked
origin with yaw 0; a structure passes *virtual* thrusts (:meth:`Structure.virtual_thrust`):
the four numbers whose wrench about the tracked origin equals the sum of every module's
wrench (the minimum-norm solution; they may be negative). A single module at the origin
with yaw 0 gives exactly its table's thrusts. A module naming a ``vehicle`` carries that
vehicle's N thrusters (its valve channels, in its thruster order) placed with the vehicle's
tracked origin at ``position_m``, turned ``yaw_deg``; its thrust is the vehicle's
(:class:`common.vehicle.Vehicle`). Such a structure is not played, run as a plant or
estimated live yet (4-channel controllers per module).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from common.body import BODY_KEYS as BODY_KEYS  # re-exported: structure.toml's [body] keys
from common.body import Body, parse_body
from common.constants import ARM_M, PAPER_IZZ_KGM2, PAPER_MASS_KG
from common.errors import UserError
from common.layout import ThrusterLayout, block_diagonal, check_parts, module_wrench_1, table_entry
from common.layout import pinv_w1 as _pinv_w1
from common.plausible import check_module_spacing
from common.thrust_table import ThrustTable, load_thrust_table
from common.thrust_uncertainty import ThrustSensitivity, thrust_sensitivity
from common.tomlfile import check_keys, read_toml, toml_pair
from common.tomlfile import toml_number as _num
from common.vehicle import Vehicle
from common.vehicle_toml import vehicle_document

TOP_KEYS = ("name", "modules", "body")
MODULE_KEYS = ("name", "position_m", "yaw_deg", "thrust_table", "vehicle", "mass_kg", "izz_kgm2")
_NAME = re.compile(r"^[A-Za-z0-9_-]+$")

def _module_vehicle(m: Mapping[str, Any], where: str, base_dir: Path | None
                    ) -> tuple[Vehicle | None, Path | None]:
    """A module entry's ``vehicle = "file.toml"`` (relative to ``base_dir``), or None."""
    if "vehicle" not in m:
        return None, None
    raw = m["vehicle"]
    if not isinstance(raw, str) or not raw:
        raise UserError(f"{where}vehicle must be a vehicle.toml file name")
    if "thrust_table" in m:
        raise UserError(f"{where}a vehicle module's tables are in its vehicle file: drop "
                        "thrust_table")
    path = Path(raw)
    if not path.is_absolute() and base_dir is not None:
        path = base_dir / path
    try:
        v = Vehicle.load(path)
    except UserError as exc:
        raise UserError(f"{where}vehicle: {exc}") from None
    if v.valves.delay_s or v.valves.rise_s:
        raise UserError(f"{where}vehicle {path}: [valves] delay_s/rise_s of a vehicle in a "
                        "structure are not built yet (use the vehicle alone, or drop them)")
    return v, path


@dataclass(frozen=True)
class Module:
    """One module of a structure.

    Attributes:
        name: identifier (letters, digits, ``_``, ``-``): its valve block and Zenoh key.
        position_m: (x, y) of the module centre in the tracked frame, m.
        yaw_deg: module x axis relative to the tracked x axis, degrees, counter-clockwise.
        table: its thrust table.
        table_path: the file the table came from, or None for the default (Table 2).
        mass_kg, izz_kgm2: known mass and Izz about the module centre, or None.
        vehicle: a :class:`common.vehicle.Vehicle` whose thrusters the module carries
            instead of the TPODS geometry (structures compose vehicles), its
            tracked origin at ``position_m`` turned by ``yaw_deg``; None for a TPODS module.
        vehicle_path: the file it came from.
    """

    name: str
    position_m: tuple[float, float] = (0.0, 0.0)
    yaw_deg: float = 0.0
    table: ThrustTable = field(default_factory=ThrustTable.default)
    table_path: Path | None = None
    mass_kg: float | None = None
    izz_kgm2: float | None = None
    vehicle: Vehicle | None = None
    vehicle_path: Path | None = None

    @property
    def n_channels(self) -> int:
        """Its valve channels: 4 (a TPODS module) or its vehicle's thrusters."""
        return 4 if self.vehicle is None else self.vehicle.n_channels

    @property
    def uses_default_table(self) -> bool:
        """True when ``--thrust-table`` would replace a table of this module."""
        if self.vehicle is None:
            return self.table_path is None
        return any(t.table is not None and t.table_path is None for t in self.vehicle.thrusters)

    def thrust_n(self, duty_pct: np.ndarray, clamp: bool = False) -> np.ndarray:
        """(..., C) thrust per thruster of the module, N, for its duty columns."""
        if self.vehicle is None:
            return self.table.thrust_n(duty_pct, clamp=clamp)
        return self.vehicle.thrust_n(duty_pct, clamp=clamp)

    def sensitivity(self, duty_pct: np.ndarray, clamp: bool = False) -> ThrustSensitivity:
        """Its thrust uncertainty per thruster (its table's, or its vehicle's)."""
        if self.vehicle is None:
            return thrust_sensitivity(self.table, duty_pct, clamp=clamp)
        return self.vehicle.thruster_sensitivity(duty_pct, clamp=clamp)

    def wrench_matrix(self, arm_m: float = ARM_M) -> np.ndarray:
        """(3, C): body-frame Fx, Fy (N) and Mz about the tracked origin (N m) per newton of
        each of the module's thrusters: the module force turned by ``yaw_deg``, the moment
        the module's own plus ``position x force``."""
        w1 = module_wrench_1(arm_m) if self.vehicle is None else self.vehicle.module_wrench_matrix()
        a = math.radians(self.yaw_deg)
        c, s = math.cos(a), math.sin(a)
        fx = c * w1[0] - s * w1[1]
        fy = s * w1[0] + c * w1[1]
        x, y = self.position_m
        mz = w1[2] + x * fy - y * fx
        return np.vstack([fx, fy, mz])


@dataclass(frozen=True)
class Structure(ThrusterLayout):
    """A rigid structure and its modules (see the module doc).

    Attributes:
        name: the structure's name.
        modules: the modules, in valve-channel order (module 1's four duties first).
        body: known values or priors of the whole body.
        source: the file it was read from (for messages), or a description.
        arm_m: thruster moment arm about each module's centre, m.
    """

    name: str
    modules: tuple[Module, ...]
    body: Body = field(default_factory=Body)
    source: str = "structure"
    arm_m: float = ARM_M

    def __post_init__(self) -> None:
        check_parts([m.name for m in self.modules], self.source, "structure", "modules", "module")
        check_module_spacing([m.name for m in self.modules], [m.position_m for m in self.modules],
                             self.source, 2 * self.arm_m)

    # ---------------------------------------------------------------- build
    @classmethod
    def single_module(cls, table: ThrustTable | None = None, name: str = "module") -> Structure:
        """One module at the tracked origin, yaw 0: today's isolated module. Its
        :meth:`virtual_thrust` is exactly ``table.thrust_n`` (default Table 2)."""
        table = table if table is not None else load_thrust_table(None)
        return cls(name, (Module(name, (0.0, 0.0), 0.0, table),), source="single module")

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], source: str = "structure.toml",
                  base_dir: Path | None = None) -> Structure:
        """A structure from parsed TOML; UserError naming ``source`` on any problem.
        ``thrust_table`` paths are relative to ``base_dir``."""
        try:
            return cls._from_dict(data, source, base_dir)
        except UserError as exc:
            msg = str(exc)
            raise UserError(msg if msg.startswith(source) else f"{source}: {msg}") from None

    @classmethod
    def _from_dict(cls, data: Mapping[str, Any], source: str, base_dir: Path | None) -> Structure:
        check_keys(data, TOP_KEYS, "")
        name = data.get("name")
        if not isinstance(name, str) or not name.strip():
            raise UserError('no name: add name = "..." (the structure\'s name)')
        raw = data.get("modules")
        if not isinstance(raw, list) or not raw:
            raise UserError("no modules: add one [[modules]] entry per module")
        cache: dict[Path, ThrustTable] = {}
        modules = []
        for i, m in enumerate(raw, start=1):
            where = f"[[modules]] #{i}: "
            if not isinstance(m, Mapping):
                raise UserError(f"{where}must be a table")
            check_keys(m, MODULE_KEYS, where)
            mname = m.get("name")
            if not isinstance(mname, str) or not _NAME.match(mname):
                raise UserError(f"{where}name must be letters, digits, '_' or '-', got {mname!r}")
            where = f"[[modules]] {mname!r}: "
            if "position_m" not in m:
                raise UserError(f"{where}no position_m: add position_m = [x, y] (m)")
            pos = toml_pair(m["position_m"], f"{where}position_m")
            yaw = _num(m.get("yaw_deg", 0.0), f"{where}yaw_deg")
            tpath = None
            table = None
            if "thrust_table" in m:
                table, tpath = table_entry(m["thrust_table"], where, base_dir, cache)
            vehicle, vpath = _module_vehicle(m, where, base_dir)
            mass = m.get("mass_kg")
            izz = m.get("izz_kgm2")
            mass = None if mass is None else _num(mass, f"{where}mass_kg", positive=True)
            izz = None if izz is None else _num(izz, f"{where}izz_kgm2", positive=True)
            modules.append(Module(mname, pos, yaw, table if table is not None else
                                  load_thrust_table(None), tpath, mass, izz, vehicle, vpath))
        body = parse_body(data["body"]) if "body" in data else Body()
        return cls(name.strip(), tuple(modules), body, source)

    @classmethod
    def load(cls, path: str | Path) -> Structure:
        """Read ``structure.toml``; UserError naming the file on any problem."""
        path = Path(path)
        data = read_toml(path, "structure file")
        return cls.from_dict(data, str(path), path.parent)

    def write(self, folder: str | Path) -> Path:
        """Write ``folder/structure.toml`` self-contained: a module with its own table gets
        it saved beside as ``<module>_thrust_table.toml``. Returns the TOML's path."""
        folder = Path(folder)
        mods = []
        for m in self.modules:
            d: dict[str, Any] = {"name": m.name, "position_m": list(m.position_m),
                                 "yaw_deg": m.yaw_deg}
            if m.table_path is not None:
                fname = f"{m.name}_thrust_table.toml"
                m.table.save(folder / fname)
                d["thrust_table"] = fname
            if m.vehicle is not None:
                v = m.vehicle
                d["vehicle"] = f"{m.name}_vehicle.toml"
                (folder / d["vehicle"]).write_text(tomli_w.dumps(vehicle_document(
                    v.name, v.thrusters, v.valves, v.body, folder, f"{m.name}_",
                    supplies=v.supplies)))
            if m.mass_kg is not None:
                d["mass_kg"] = m.mass_kg
            if m.izz_kgm2 is not None:
                d["izz_kgm2"] = m.izz_kgm2
            mods.append(d)
        out: dict[str, Any] = {"name": self.name, "modules": mods}
        if self.body.to_dict():
            out["body"] = self.body.to_dict()
        path = folder / "structure.toml"
        path.write_text(tomli_w.dumps(out))
        return path

    def with_table(self, table: ThrustTable) -> Structure:
        """A copy in which every module whose entry names no ``thrust_table`` uses ``table``
        instead of the default (what ``--thrust-table`` means for a structure run; see
        :meth:`check_table_option`)."""
        return replace(self, modules=tuple(
            replace(m, vehicle=m.vehicle.with_table(table)) if m.vehicle is not None else
            m if m.table_path is not None else replace(m, table=table) for m in self.modules))

    def check_table_option(self, option: str = "--thrust-table") -> None:
        """UserError when every module names its own ``thrust_table``: a table given on
        the command line would then be ignored."""
        if not any(m.uses_default_table for m in self.modules):
            raise UserError(f"{self.source}: every module names its own thrust_table; "
                            f"{option} would be ignored (drop it)")

    # ---------------------------------------------------------------- shape
    @property
    def n_modules(self) -> int:
        return len(self.modules)

    def initial_guess(self) -> dict[str, float]:
        """A start for the estimators from what the file says: ``mass``, ``izz`` (about the
        centre of mass) and ``cx, cy``. The [body] values where given; else the modules as
        point-like parts: each module's mass_kg/izz_kgm2 (default the paper's module, 2.268 kg,
        3.78e-3 kg m^2) at its position, by the parallel-axis theorem (the truss's own mass is
        not known: a start, not an estimate)."""
        ms = np.array([m.mass_kg if m.mass_kg is not None else PAPER_MASS_KG for m in self.modules])
        iz = np.array([m.izz_kgm2 if m.izz_kgm2 is not None else PAPER_IZZ_KGM2
                       for m in self.modules])
        pos = np.array([m.position_m for m in self.modules], dtype=float)
        mass = float(ms.sum())
        c = (ms[:, None] * pos).sum(axis=0) / mass
        izz = float(np.sum(iz + ms * np.sum((pos - c) ** 2, axis=1)))
        b = self.body
        out = {"mass": mass, "izz": izz, "cx": float(c[0]), "cy": float(c[1])}
        if b.mass_kg is not None:
            out["mass"] = float(b.mass_kg)
        if b.izz_kgm2 is not None:
            out["izz"] = float(b.izz_kgm2)
        if b.com_m is not None:
            out["cx"], out["cy"] = (float(v) for v in b.com_m)
        return out

    @property
    def n_channels(self) -> int:
        """Valve channels: 4 per module."""
        return sum(m.n_channels for m in self.modules)

    def _slices(self) -> list[tuple[int, int]]:
        """``(first, end)`` channel of every module (module 1's first)."""
        ends = np.cumsum([m.n_channels for m in self.modules]).tolist()
        return list(zip([0] + ends[:-1], ends, strict=True))

    @property
    def is_single_at_origin(self) -> bool:
        """One module at the tracked origin with yaw 0 (today's isolated module)."""
        m = self.modules[0]
        return (len(self.modules) == 1 and m.position_m == (0.0, 0.0) and m.yaw_deg == 0.0
                and m.vehicle is None)

    def module_wrench_matrix(self) -> np.ndarray:
        """(3, 4N): body-frame Fx, Fy (N) and Mz about the tracked origin (N m) per newton
        of every thruster, module 1's four columns first."""
        return np.hstack([m.wrench_matrix(self.arm_m) for m in self.modules])

    def _duty_error(self, n_given: int) -> str:
        return (f"{self.source}: {self.n_modules} module(s) need {self.n_channels} duty "
                f"columns (d1..d{self.n_channels}), got {n_given}")

    kind = "structure"

    def parts_text(self) -> str:
        return f"{self.n_modules} modules"

    def single_table(self) -> ThrustTable:
        """The table of module 1 (the one table of a single module at the origin)."""
        return self.modules[0].table

    def extent_m(self) -> float:
        """The farthest thruster from the tracked origin, m (a module's centre distance
        plus its thrusters' arm)."""
        if all(m.vehicle is None for m in self.modules):
            return max(math.hypot(*m.position_m) for m in self.modules) + self.arm_m
        return max(math.hypot(*m.position_m) + (self.arm_m if m.vehicle is None else
                                                  m.vehicle.extent_m()) for m in self.modules)

    def tables(self) -> tuple[ThrustTable, ...]:
        """Every module's table (a vehicle module's tables), in module order."""
        return tuple(t for m in self.modules
                     for t in ((m.table,) if m.vehicle is None else m.vehicle.tables()))

    # ---------------------------------------------------------------- thrust
    def thrust_n(self, duty_pct: np.ndarray, clamp: bool = False) -> np.ndarray:
        """(..., 4N) thrust per physical thruster, N, from duty (..., 4N) in percent: module
        m's four columns through module m's table with k = open valves of module m."""
        d = self._check_duty(duty_pct)
        out = np.empty_like(d)
        for m, (a, b) in zip(self.modules, self._slices(), strict=True):
            try:
                out[..., a:b] = m.thrust_n(d[..., a:b], clamp=clamp)
            except UserError as exc:
                raise UserError(f"module {m.name} (d{a + 1}..d{b}): {exc}") from None
        return out

    def virtual_sensitivity(self, duty_pct: np.ndarray, clamp: bool = False) -> ThrustSensitivity:
        """The thrust-table uncertainty of every module mapped to the virtual thrusts:
        ``thrust_n`` (..., 4), ``jacobian`` (..., 4, P) = ``pinv(W1) @ W_m`` applied to
        module m's per-thruster jacobian, parameter names prefixed ``<module>:``
        (``tpods1:scale``), covariance block-diagonal (modules' tables independent).
        A single module at the origin gives :func:`thrust_sensitivity` of its table."""
        d = self._check_duty(duty_pct)
        if self.is_single_at_origin:
            return thrust_sensitivity(self.modules[0].table, d, clamp=clamp)
        pinv = _pinv_w1(self.arm_m)
        thrust = np.zeros(d.shape[:-1] + (4,))
        jacs, names, blocks = [], [], []
        for m, (a, b) in zip(self.modules, self._slices(), strict=True):
            try:
                s = m.sensitivity(d[..., a:b], clamp=clamp)
            except UserError as exc:
                raise UserError(f"module {m.name} (d{a + 1}..d{b}): {exc}") from None
            p = pinv @ m.wrench_matrix(self.arm_m)  # (4, C)
            thrust = thrust + s.thrust_n @ p.T
            jacs.append(np.einsum("ij,...jp->...ip", p, s.jacobian))
            names.extend(f"{m.name}:{n}" for n in s.names)
            blocks.append(s.covariance)
        cov = block_diagonal(blocks)
        jac = np.concatenate(jacs, axis=-1) if jacs else np.zeros(thrust.shape + (0,))
        return ThrustSensitivity(thrust, jac, tuple(names), cov)

    @property
    def states_uncertainty(self) -> bool:
        """True when any module's table (a vehicle module's tables or valve forces) states
        an uncertainty."""
        return any(m.table.states_uncertainty if m.vehicle is None else m.vehicle.states_uncertainty
                   for m in self.modules)

    def describe(self) -> list[str]:
        """One line per module (for summaries)."""
        return [f"{m.name}: position ({m.position_m[0]:g}, {m.position_m[1]:g}) m, yaw "
                f"{m.yaw_deg:g} deg, " + (f"table {m.table_path or 'Table 2 (default)'}"
                                          if m.vehicle is None else
                                          f"vehicle {m.vehicle.name} ({m.vehicle.n_channels} "
                                          f"thrusters, {m.vehicle_path})")
                for m in self.modules]


def load_structure(path: str | Path | None) -> Structure | None:
    """The structure at ``path`` (None: None)."""
    return None if path is None else Structure.load(path)
