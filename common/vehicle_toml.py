"""The parts of a vehicle and its file (issue 24, docs/run-format.md "Vehicle runs"):
:class:`Thruster`, :class:`Valves`, the parser of ``vehicle.toml``
(:func:`parse_vehicle`: one UserError naming the file and the key, unknown keys with a
did-you-mean) and its writer (:func:`vehicle_document`). :class:`common.vehicle.Vehicle`
is built from them."""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from common.body import Body, parse_body
from common.errors import UserError
from common.layout import table_entry
from common.thrust_table import ThrustTable
from common.tomlfile import check_keys, toml_number, toml_pair

TOP_KEYS = ("vehicle", "thrusters", "valves", "body")
VEHICLE_KEYS = ("name",)
THRUSTER_KEYS = ("name", "position_m", "direction", "force_n", "force_sigma_n", "thrust_table",
                 "supply")
VALVE_KEYS = ("delay_s", "rise_s")
DEFAULT_SUPPLY = "main"
DEFAULT_TABLE = "default"
"""``thrust_table = "default"``: the built-in Table 2 (what ``--thrust-table`` replaces)."""
DIRECTION_NORM = (0.9, 1.1)
_NAME = re.compile(r"^[A-Za-z0-9_-]+$")


@dataclass(frozen=True)
class Thruster:
    """One thruster: ``position_m`` (m) and unit ``direction`` in the tracked body frame;
    ``force_n`` (on/off valve, N) or ``table`` (``table_path`` None: the built-in
    default); ``force_sigma_n`` the 1-sigma of ``force_n``; ``supply`` its regulator."""

    name: str
    position_m: tuple[float, float]
    direction: tuple[float, float]
    force_n: float | None = None
    force_sigma_n: float | None = None
    table: ThrustTable | None = None
    table_path: Path | None = None
    supply: str = DEFAULT_SUPPLY

    def wrench_column(self) -> np.ndarray:
        """(3,) ``[dx, dy, x dy - y dx]``: Fx, Fy (N) and Mz about the tracked origin (N m)
        per newton of thrust."""
        (x, y), (dx, dy) = self.position_m, self.direction
        return np.array([dx, dy, x * dy - y * dx])


@dataclass(frozen=True)
class Valves:
    """``[valves]``: known dead time ``delay_s`` and first-order rise ``rise_s``, s."""

    delay_s: float = 0.0
    rise_s: float = 0.0


def _name(x: Any, what: str) -> str:
    if not isinstance(x, str) or not _NAME.match(x):
        raise UserError(f"{what} must be letters, digits, '_' or '-', got {x!r}")
    return x


def _thruster(t: Any, i: int, base_dir: Path | None,
              cache: dict[Path | None, ThrustTable]) -> Thruster:
    where = f"[[thrusters]] #{i}: "
    if not isinstance(t, Mapping):
        raise UserError(f"{where}must be a table")
    name = _name(t.get("name"), f"{where}name")
    where = f"[[thrusters]] {name!r}: "
    check_keys(t, THRUSTER_KEYS, where)
    for key, what in (("position_m", "[x, y] (m, body frame)"), ("direction", "[dx, dy] (unit)")):
        if key not in t:
            raise UserError(f"{where}no {key}: add {key} = {what}")
    pos = toml_pair(t["position_m"], f"{where}position_m")
    dx, dy = toml_pair(t["direction"], f"{where}direction")
    norm = math.hypot(dx, dy)
    if not DIRECTION_NORM[0] <= norm <= DIRECTION_NORM[1]:
        raise UserError(f"{where}direction must be a unit vector (|d| {DIRECTION_NORM[0]:g}.."
                        f"{DIRECTION_NORM[1]:g}), got |d| = {norm:.4g}")
    if norm != 1.0:
        dx, dy = dx / norm, dy / norm
    has_f, has_t = "force_n" in t, "thrust_table" in t
    if has_f == has_t:
        raise UserError(f"{where}give either force_n (an on/off valve, N) or thrust_table "
                        f"(a table file or \"{DEFAULT_TABLE}\"), {'not both' if has_f else 'one of them'}")
    supply = _name(t.get("supply", DEFAULT_SUPPLY), f"{where}supply")
    if has_f:
        force = toml_number(t["force_n"], f"{where}force_n", positive=True)
        sigma = t.get("force_sigma_n")
        sigma = None if sigma is None else toml_number(sigma, f"{where}force_sigma_n", nonneg=True)
        return Thruster(name, pos, (dx, dy), force, sigma, supply=supply)
    if "force_sigma_n" in t:
        raise UserError(f"{where}force_sigma_n is for force_n; a table states its own uncertainty")
    table, path = table_entry(t["thrust_table"], where, base_dir, cache, DEFAULT_TABLE)
    return Thruster(name, pos, (dx, dy), table=table, table_path=path, supply=supply)


def parse_vehicle(data: Mapping[str, Any], source: str = "vehicle.toml", base_dir: Path | None = None
                  ) -> tuple[str, tuple[Thruster, ...], Valves, Body]:
    """``(name, thrusters, valves, body)`` of a parsed vehicle.toml; UserError
    ``<source>: <key>: ...`` on any problem."""
    try:
        return _parse(data, base_dir)
    except UserError as exc:
        raise UserError(f"{source}: {exc}") from None


def _parse(data: Mapping[str, Any], base_dir: Path | None
           ) -> tuple[str, tuple[Thruster, ...], Valves, Body]:
    check_keys(data, TOP_KEYS, "")
    v = data.get("vehicle")
    if not isinstance(v, Mapping):
        raise UserError('no [vehicle] table: add [vehicle] with name = "..."')
    check_keys(v, VEHICLE_KEYS, "[vehicle]: ")
    name = _name(v.get("name"), "[vehicle] name")
    raw = data.get("thrusters")
    if not isinstance(raw, list) or not raw:
        raise UserError("no thrusters: add one [[thrusters]] entry per thruster")
    cache: dict[Path | None, ThrustTable] = {}
    thrusters = tuple(_thruster(t, i, base_dir, cache) for i, t in enumerate(raw, start=1))
    valves = Valves()
    if "valves" in data:
        vv = data["valves"]
        if not isinstance(vv, Mapping):
            raise UserError("[valves] must be a table")
        check_keys(vv, VALVE_KEYS, "[valves]: ")
        valves = Valves(**{k: toml_number(vv[k], f"[valves] {k}", nonneg=True) for k in vv})
    body = parse_body(data["body"]) if "body" in data else Body()
    return name, thrusters, valves, body


def vehicle_document(name: str, thrusters: tuple[Thruster, ...], valves: Valves, body: Body,
                     folder: Path, prefix: str = "") -> dict[str, Any]:
    """The TOML document of a vehicle, self-contained in ``folder``: a table read from a
    file is saved there as ``<prefix>thrust_table_<supply>.toml``; the built-in one stays
    ``"default"``."""
    out: dict[str, Any] = {"vehicle": {"name": name}, "thrusters": []}
    for t in thrusters:
        d: dict[str, Any] = {"name": t.name, "position_m": list(t.position_m),
                             "direction": list(t.direction)}
        if t.table is None:
            d["force_n"] = t.force_n
            if t.force_sigma_n is not None:
                d["force_sigma_n"] = t.force_sigma_n
        elif t.table_path is None:
            d["thrust_table"] = DEFAULT_TABLE
        else:
            fname = f"{prefix}thrust_table_{t.supply}.toml"
            t.table.save(folder / fname)
            d["thrust_table"] = fname
        d["supply"] = t.supply
        out["thrusters"].append(d)
    if valves != Valves():
        out["valves"] = {"delay_s": valves.delay_s, "rise_s": valves.rise_s}
    if body.to_dict():
        out["body"] = body.to_dict()
    return out
