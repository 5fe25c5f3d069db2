"""The parts of a vehicle and its file (docs/run-format.md "Vehicle runs"):
:class:`Thruster`, :class:`Valves`, :class:`Supply` (a shared supply's drop), the parser of ``vehicle.toml``
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
from common.plausible_inputs import check_force_n, check_force_sigma_n, check_time_s
from common.thrust_table import ThrustTable
from common.tomlfile import check_keys, toml_number, toml_pair

TOP_KEYS = ("vehicle", "thrusters", "valves", "supplies", "body")
VEHICLE_KEYS = ("name",)
THRUSTER_KEYS = ("name", "position_m", "direction", "force_n", "force_sigma_n", "thrust_table", "health",
                 "supply")
VALVE_KEYS = ("delay_s", "rise_s", "delay_sigma_s")
SUPPLY_KEYS = ("drop_per_valve", "drop_sigma")
DEFAULT_SUPPLY = "main"
HEALTH_VERDICTS = ("ok", "weak", "dead", "reversed", "stuck-open")
"""``health`` of a thruster (``tpods estimate batch --thruster-health --out-vehicle``): a
``"dead"`` thruster gives no thrust in every estimator; the others are a record."""
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
    health: str = "ok"

    @property
    def dead(self) -> bool:
        """Marked ``health = "dead"``: every estimator takes it as giving no thrust."""
        return self.health == "dead"

    def wrench_column(self) -> np.ndarray:
        """(3,) ``[dx, dy, x dy - y dx]``: Fx, Fy (N) and Mz about the tracked origin (N m)
        per newton of thrust."""
        (x, y), (dx, dy) = self.position_m, self.direction
        return np.array([dx, dy, x * dy - y * dx])


@dataclass(frozen=True)
class Valves:
    """``[valves]``: known dead time ``delay_s`` and first-order rise ``rise_s``, s; the
    1-sigma of ``delay_s``, ``delay_sigma_s`` (s; None: not stated)."""

    delay_s: float = 0.0
    rise_s: float = 0.0
    delay_sigma_s: float | None = None


@dataclass(frozen=True)
class Supply:
    """``[supplies.<name>]``: the fraction ``drop_per_valve`` of its force that every open
    on/off valve of the supply loses per OTHER valve open on it at the same instant (its
    force is ``force_n * (1 - drop_per_valve * (k - 1))`` with k open), and its optional
    1-sigma ``drop_sigma``."""

    name: str
    drop_per_valve: float = 0.0
    drop_sigma: float | None = None


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
    health = t.get("health", "ok")
    if health not in HEALTH_VERDICTS:
        raise UserError(f"{where}health must be one of {', '.join(HEALTH_VERDICTS)}, got {health!r}")
    if has_f:
        force = check_force_n(toml_number(t["force_n"], f"{where}force_n", positive=True),
                              f"{where}force_n")
        sigma = t.get("force_sigma_n")
        sigma = None if sigma is None else check_force_sigma_n(
            toml_number(sigma, f"{where}force_sigma_n", nonneg=True), force,
            f"{where}force_sigma_n")
        return Thruster(name, pos, (dx, dy), force, sigma, supply=supply, health=health)
    if "force_sigma_n" in t:
        raise UserError(f"{where}force_sigma_n is for force_n; a table states its own uncertainty")
    table, path = table_entry(t["thrust_table"], where, base_dir, cache, DEFAULT_TABLE)
    return Thruster(name, pos, (dx, dy), table=table, table_path=path, supply=supply,
                    health=health)


def parse_vehicle(data: Mapping[str, Any], source: str = "vehicle.toml", base_dir: Path | None = None
                  ) -> tuple[str, tuple[Thruster, ...], Valves, Body, tuple[Supply, ...]]:
    """``(name, thrusters, valves, body, supplies)`` of a parsed vehicle.toml; UserError
    ``<source>: <key>: ...`` on any problem."""
    try:
        return _parse(data, base_dir)
    except UserError as exc:
        raise UserError(f"{source}: {exc}") from None


def _parse(data: Mapping[str, Any], base_dir: Path | None
           ) -> tuple[str, tuple[Thruster, ...], Valves, Body, tuple[Supply, ...]]:
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
        valves = Valves(**{k: check_time_s(toml_number(vv[k], f"[valves] {k}", nonneg=True),
                                           f"[valves] {k}") for k in vv})
    body = parse_body(data["body"]) if "body" in data else Body()
    return name, thrusters, valves, body, _supplies(data.get("supplies"), thrusters)


def _supplies(raw: Any, thrusters: tuple[Thruster, ...]) -> tuple[Supply, ...]:
    """``[supplies.<name>]`` tables: a drop per other open valve ``0 <= drop < 1/(n-1)``
    (n on/off valves on the supply: the force stays positive with all of them open)."""
    if raw is None:
        return ()
    if not isinstance(raw, Mapping):
        raise UserError("[supplies] must hold tables [supplies.<name>]")
    out = []
    for name, entry in raw.items():
        where = f"[supplies.{name}] "
        on = [t for t in thrusters if t.supply == name]
        if not on:
            used = ", ".join(dict.fromkeys(t.supply for t in thrusters))
            raise UserError(f"{where}names no supply of a thruster (supplies: {used})")
        if not isinstance(entry, Mapping):
            raise UserError(f"{where}must be a table")
        check_keys(entry, SUPPLY_KEYS, where)
        if any(t.table is not None for t in on):
            raise UserError(f"{where}drop_per_valve is for on/off force_n valves; a thrust "
                            "table states its own force per number of valves open")
        drop = toml_number(entry.get("drop_per_valve", 0.0), f"{where}drop_per_valve", nonneg=True)
        limit = 1.0 / max(len(on) - 1, 1)
        if not drop < limit:
            raise UserError(f"{where}drop_per_valve must be >= 0 and < 1/(n-1) = {limit:.4g} "
                            f"with n = {len(on)} valves on the supply, got {drop:g}")
        sigma = entry.get("drop_sigma")
        sigma = None if sigma is None else toml_number(sigma, f"{where}drop_sigma", nonneg=True)
        out.append(Supply(name, drop, sigma))
    return tuple(out)


def vehicle_document(name: str, thrusters: tuple[Thruster, ...], valves: Valves, body: Body,
                     folder: Path, prefix: str = "", supplies: tuple[Supply, ...] = ()
                     ) -> dict[str, Any]:
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
        if t.health != "ok":
            d["health"] = t.health
        out["thrusters"].append(d)
    if valves != Valves():
        out["valves"] = {"delay_s": valves.delay_s, "rise_s": valves.rise_s,
                         **({} if valves.delay_sigma_s is None
                            else {"delay_sigma_s": valves.delay_sigma_s})}
    kept = {s.name: {"drop_per_valve": s.drop_per_valve,
                     **({} if s.drop_sigma is None else {"drop_sigma": s.drop_sigma})}
            for s in supplies if s.drop_per_valve or s.drop_sigma is not None}
    if kept:
        out["supplies"] = kept
    if body.to_dict():
        out["body"] = body.to_dict()
    return out
