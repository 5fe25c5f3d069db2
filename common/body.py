"""``[body]`` of structure.toml and vehicle.toml: known values or priors of the whole rigid
body (mass, Izz about the centre of mass, centre of mass in the tracked frame) --
:class:`Body` and its parser :func:`parse_body` (one UserError line naming the key)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from common.errors import UserError
from common.tomlfile import check_keys, toml_number, toml_pair

BODY_KEYS = ("mass_kg", "mass_sigma_kg", "izz_kgm2", "izz_sigma_kgm2", "com_m", "com_sigma_m")


@dataclass(frozen=True)
class Body:
    """``[body]``: known values or priors of the whole structure (None: unknown).

    A value without a sigma (or with sigma 0) is known; with a sigma it is a prior.
    Units: kg, kg m^2 (about the centre of mass), m (centre of mass in the tracked frame).
    """

    mass_kg: float | None = None
    mass_sigma_kg: float | None = None
    izz_kgm2: float | None = None
    izz_sigma_kgm2: float | None = None
    com_m: tuple[float, float] | None = None
    com_sigma_m: tuple[float, float] | None = None

    def _entries(self) -> list[tuple[str, float, float | None]]:
        """``(parameter, value, sigma or None)`` of every given value, in the estimators'
        names (mass, izz, cx, cy)."""
        out = []
        if self.mass_kg is not None:
            out.append(("mass", float(self.mass_kg), self.mass_sigma_kg))
        if self.izz_kgm2 is not None:
            out.append(("izz", float(self.izz_kgm2), self.izz_sigma_kgm2))
        if self.com_m is not None:
            s = self.com_sigma_m or (None, None)
            out += [("cx", float(self.com_m[0]), s[0]), ("cy", float(self.com_m[1]), s[1])]
        return out

    def known(self) -> dict[str, float]:
        """The known values (no sigma, or sigma 0) by parameter name: ``mass`` (kg), ``izz``
        (kg m^2 about the centre of mass), ``cx``, ``cy`` (m, tracked frame). The estimators
        fix them unless told to estimate them."""
        return {n: v for n, v, s in self._entries() if not s}

    def priors(self) -> dict[str, tuple[float, float]]:
        """The Gaussian priors ``name -> (mean, sigma)`` (a value with a sigma > 0), in the
        units of :meth:`known`."""
        return {n: (v, float(s)) for n, v, s in self._entries() if s}

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for k in BODY_KEYS:
            v = getattr(self, k)
            if v is not None:
                out[k] = list(v) if isinstance(v, tuple) else v
        return out


def parse_body(b: Any) -> Body:
    """The :class:`Body` of a parsed ``[body]`` table; UserError ``[body] <key>: ...``."""
    if not isinstance(b, Mapping):
        raise UserError("[body] must be a table")
    check_keys(b, BODY_KEYS, "[body]: ")
    kw: dict[str, Any] = {}
    for k in ("mass_kg", "izz_kgm2"):
        if k in b:
            kw[k] = toml_number(b[k], f"[body] {k}", positive=True)
    for k in ("mass_sigma_kg", "izz_sigma_kgm2"):
        if k in b:
            kw[k] = toml_number(b[k], f"[body] {k}", nonneg=True)
    if "com_m" in b:
        kw["com_m"] = toml_pair(b["com_m"], "[body] com_m")
    if "com_sigma_m" in b:
        s = b["com_sigma_m"]
        sx, sy = (s, s) if not isinstance(s, list | tuple) else toml_pair(s, "[body] com_sigma_m")
        kw["com_sigma_m"] = (toml_number(sx, "[body] com_sigma_m", nonneg=True),
                             toml_number(sy, "[body] com_sigma_m", nonneg=True))
    for v, s in (("mass_kg", "mass_sigma_kg"), ("izz_kgm2", "izz_sigma_kgm2"),
                 ("com_m", "com_sigma_m")):
        if s in kw and v not in kw:
            raise UserError(f"[body] {s} given without {v}")
    return Body(**kw)
