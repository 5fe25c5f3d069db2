"""Which thruster layout a file or a run folder holds: ``structure.toml`` or
``vehicle.toml`` -- :func:`load_layout` (by ``--vehicle`` or by the file's content),
:func:`as_layout`, :func:`folder_layout` (a run folder's file) and
:func:`load_structure_only` (for the commands that take no vehicle yet) and
:func:`load_live_layout` (the live commands: a structure or a vehicle, not both in one)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from common.argtypes import VehicleFile
from common.errors import UserError
from common.layout import ThrusterLayout
from common.structure import Structure
from common.tomlfile import read_toml
from common.vehicle import Vehicle

LAYOUT_FILES = ("structure.toml", "vehicle.toml")


def load_layout(path: str | Path) -> Structure | Vehicle:
    """A structure.toml or a vehicle.toml: a :class:`VehicleFile` (``--vehicle``) or a
    file with a ``[vehicle]`` table is read as a :class:`Vehicle`, any other as a
    :class:`common.structure.Structure`. UserError naming the file on any problem."""
    if isinstance(path, VehicleFile):
        return Vehicle.load(path)
    path = Path(path)
    data = read_toml(path, "vehicle file" if path.name == "vehicle.toml" else "structure file")
    if "vehicle" in data or "thrusters" in data:
        return Vehicle.from_dict(data, str(path), path.parent)
    return Structure.from_dict(data, str(path), path.parent)


def as_layout(layout: Any) -> Structure | Vehicle | None:
    """``layout`` as a structure or vehicle: one already (returned as is), its file
    (:func:`load_layout`), or None."""
    if layout is None or isinstance(layout, ThrusterLayout):
        return layout
    return load_layout(layout)


def folder_layout(folder: str | Path) -> Path | None:
    """The structure.toml or vehicle.toml of a run folder, None without; UserError when
    it holds both (a run is either)."""
    found = [Path(folder) / f for f in LAYOUT_FILES if (Path(folder) / f).is_file()]
    if len(found) > 1:
        raise UserError(f"{folder}: holds both structure.toml and vehicle.toml; a run is a "
                        "structure run or a vehicle run: remove one")
    return found[0] if found else None


def load_live_layout(path: str | Path) -> Structure | Vehicle:
    """The structure or vehicle at ``path`` for the live commands (``estimate live``, ``run
    play``, ``run plant``): a structure with a vehicle module is refused in one line (its
    modules' streams are 4 duties each; simulate it with ``tpods sim``)."""
    layout = load_layout(path)
    if isinstance(layout, Structure) and any(m.vehicle is not None for m in layout.modules):
        raise UserError(f"{layout.source}: a structure with a vehicle module is not run live yet "
                        "(every module's command stream is 4 duties); give the vehicle itself "
                        "with --vehicle, or simulate the structure with tpods sim")
    return layout


def load_structure_only(path: str | Path, command: str, why: str) -> Structure:
    """The structure at ``path`` for a command that does not take a vehicle yet: a vehicle
    file, or a structure with a vehicle module, is refused in one line naming ``command``
    and ``why``."""
    layout = load_layout(path)
    if isinstance(layout, Vehicle) or any(m.vehicle is not None for m in layout.modules):
        raise UserError(f"{command} does not take a vehicle yet ({why})")
    return layout


def split_layout(path: str | Path | None) -> tuple[Structure | None, Vehicle | None]:
    """``(structure, vehicle)`` of a ``--structure``/``--vehicle`` file: the one it holds,
    the other None (both None without a file); refused as :func:`load_live_layout` does."""
    if not path:
        return None, None
    layout = load_live_layout(path)
    return (None, layout) if layout.kind == "vehicle" else (layout, None)
