"""What structures and vehicles share: the wrench of one TPODS module
(:func:`module_wrench_1`, its exact pseudo-inverse :func:`pinv_w1`), the plant's *virtual*
thrusts and the base class :class:`ThrusterLayout` that gives every consumer the same
interface for a :class:`common.structure.Structure` and a :class:`common.vehicle.Vehicle`.

The plant (:mod:`estimator.plant.model`) takes the four thrusts of ONE module at the
tracked origin with yaw 0; a layout of N thrusters passes the four *virtual* thrusts whose
wrench about the tracked origin equals the layout's (``pinv(W1) @ W``, the minimum-norm
solution; they may be negative). A wrench ``(fx, fy, mz)`` in the body frame maps exactly
onto virtual thrusts (:func:`virtual_from_wrench`: W1 has full row rank).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from common.constants import ARM_M
from common.errors import UserError
from common.thrust_table import ThrustTable, load_thrust_table
from common.thrust_uncertainty import ThrustSensitivity

_S = math.sqrt(0.5)


def module_wrench_1(arm_m: float = ARM_M) -> np.ndarray:
    """(3, 4) wrench matrix of one module in its own frame: rows Fx (N), Fy (N), Mz (N m
    about the module centre) per thruster newton (docs/run-format.md, "Thruster geometry")."""
    return np.array([[-_S, _S, _S, -_S],
                     [_S, _S, -_S, -_S],
                     [arm_m, -arm_m, arm_m, -arm_m]])


def pinv_w1(arm_m: float = ARM_M) -> np.ndarray:
    """(4, 3) pseudo-inverse of :func:`module_wrench_1`: its rows are orthogonal, so
    ``pinv = W1^T diag(1/|row|^2)`` (exact; no SVD)."""
    w1 = module_wrench_1(arm_m)
    return w1.T / np.sum(w1 * w1, axis=1)


def virtual_from_wrench(wrench: np.ndarray, arm_m: float = ARM_M) -> np.ndarray:
    """(..., 4) virtual thrusts, N, whose wrench is ``wrench`` (..., 3): body-frame fx, fy
    (N) and mz about the tracked origin (N m). Exact: ``W1 @ pinv(W1) = I``."""
    return np.asarray(wrench, dtype=float) @ pinv_w1(arm_m).T


def check_parts(names: Sequence[str], source: str, kind: str, entry: str, what: str) -> None:
    """UserError when a ``kind`` (structure, vehicle) has no ``[[entry]]`` or two parts
    (``what``: module, thruster) share a name."""
    if not names:
        raise UserError(f"{source}: a {kind} needs at least one [[{entry}]] entry")
    seen: set[str] = set()
    for n in names:
        if n in seen:
            raise UserError(f"{source}: {what} name {n!r} appears twice")
        seen.add(n)


def table_entry(raw: Any, where: str, base_dir: Path | None,
                cache: dict[Path | None, ThrustTable], default: str | None = None
                ) -> tuple[ThrustTable, Path | None]:
    """``(table, path)`` of a ``thrust_table = "..."`` entry: a file relative to
    ``base_dir`` (each file read once through ``cache``), or the built-in Table 2 with path
    None when ``raw`` is ``default`` (a vehicle's ``"default"``)."""
    if not isinstance(raw, str) or not raw:
        alt = f" or \"{default}\"" if default else ""
        raise UserError(f"{where}thrust_table must be a file name{alt}")
    path = None
    if raw != default:
        path = Path(raw)
        if not path.is_absolute() and base_dir is not None:
            path = base_dir / path
    if path not in cache:
        try:
            cache[path] = load_thrust_table(path)
        except UserError as exc:
            raise UserError(f"{where}thrust_table: {exc}") from None
    return cache[path], path


def block_diagonal(blocks: Sequence[np.ndarray]) -> np.ndarray:
    """The block-diagonal matrix of square ``blocks`` (independent parameter groups)."""
    n = sum(len(b) for b in blocks)
    out = np.zeros((n, n))
    j = 0
    for b in blocks:
        out[j:j + len(b), j:j + len(b)] = b
        j += len(b)
    return out


class ThrusterLayout:
    """The interface every consumer takes (sim, batch LS, CRLB, live, Monte Carlo, design,
    calibrate, run): N valve channels whose thrusts map to the plant's four virtual
    thrusts. Subclasses (frozen dataclasses) give ``source``, ``arm_m``, ``body``,
    :attr:`n_channels`, :meth:`module_wrench_matrix`, :meth:`thrust_n`,
    :attr:`is_single_at_origin` with :meth:`single_table`, and the rest of the interface
    (:meth:`virtual_sensitivity`, :meth:`initial_guess`, :meth:`describe`, :meth:`write`,
    :meth:`with_table`, :meth:`check_table_option`, :attr:`states_uncertainty`)."""

    source: str
    arm_m: float

    @property
    def n_channels(self) -> int:  # pragma: no cover - every subclass overrides it
        raise NotImplementedError

    @property
    def is_single_at_origin(self) -> bool:  # pragma: no cover
        raise NotImplementedError

    def module_wrench_matrix(self) -> np.ndarray:  # pragma: no cover
        raise NotImplementedError

    def thrust_n(self, duty_pct: np.ndarray, clamp: bool = False) -> np.ndarray:  # pragma: no cover
        raise NotImplementedError

    def single_table(self) -> ThrustTable:  # pragma: no cover
        """The one table of a layout that :attr:`is_single_at_origin`."""
        raise NotImplementedError

    kind = "layout"
    """What it is in messages: ``structure`` or ``vehicle``."""

    def parts_text(self) -> str:  # pragma: no cover
        """What it is made of, for summaries: ``2 modules``, ``8 thrusters``."""
        raise NotImplementedError

    def _duty_error(self, n_given: int) -> str:
        return (f"{self.source}: need {self.n_channels} duty columns (d1..d{self.n_channels}), "
                f"got {n_given}")

    def _check_duty(self, duty_pct: np.ndarray) -> np.ndarray:
        d = np.asarray(duty_pct, dtype=float)
        if d.ndim == 0 or d.shape[-1] != self.n_channels:
            raise UserError(self._duty_error(d.shape[-1] if d.ndim else 0))
        return d

    def command_columns(self) -> tuple[str, ...]:
        """Header of the layout's commands.csv: ``t, d1 .. dN``."""
        return ("t",) + tuple(f"d{i}" for i in range(1, self.n_channels + 1))

    def thrust_columns(self) -> tuple[str, ...]:
        """Header of the layout's thrusts.csv: ``t, T1 .. TN``."""
        return ("t",) + tuple(f"T{i}" for i in range(1, self.n_channels + 1))

    def virtual_matrix(self) -> np.ndarray:
        """(4, N) ``pinv(W1) @ module_wrench_matrix()``: physical thrusts to the virtual
        thrusts of one module at the tracked origin with the same wrench."""
        return pinv_w1(self.arm_m) @ self.module_wrench_matrix()

    def virtual_from_thrust(self, thrust_n: np.ndarray) -> np.ndarray:
        """(..., 4) virtual thrusts, N, of physical thrusts (..., N) (min-norm, may be
        negative). Exactly ``thrust_n`` for a single module at the origin."""
        t = np.asarray(thrust_n, dtype=float)
        if t.shape[-1] != self.n_channels:
            raise UserError(f"{self.source}: need {self.n_channels} thrust columns, got {t.shape[-1]}")
        if self.is_single_at_origin:
            return t
        return t @ self.virtual_matrix().T

    def virtual_thrust(self, duty_pct: np.ndarray, clamp: bool = False) -> np.ndarray:
        """(..., 4) virtual thrusts, N, for duty rows (..., N) in percent: what the plant
        takes as ``thrust_n`` (its wrench about the tracked origin is the layout's).
        A single module at the origin gives exactly ``table.thrust_n(duty)``."""
        if self.is_single_at_origin:
            d = self._check_duty(duty_pct)
            return self.single_table().thrust_n(d, clamp=clamp)
        return self.virtual_from_thrust(self.thrust_n(duty_pct, clamp=clamp))

    def input_profile(self, cmd_t: np.ndarray, duty_pct: np.ndarray,
                      clamp: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """The plant's input of commands ``(cmd_t (Nc,), duty_pct (Nc, N))``: switch times
        and virtual thrusts as a zero-order hold (the last row ends the span). Here the
        commands' own times; a vehicle with valve dead time or rise overrides it."""
        return np.asarray(cmd_t, dtype=float), self.virtual_thrust(duty_pct, clamp=clamp)

    def through_valves(self, t: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A hold ``(t (N,), rows (N, ...))`` of values linear in the thrusts seen through
        the valves' timing: here unchanged (a vehicle applies its dead time and rise)."""
        return np.asarray(t, dtype=float), np.asarray(rows, dtype=float)

    def input_sensitivity(self, cmd_t: np.ndarray, duty_pct: np.ndarray, clamp: bool = False
                          ) -> tuple[np.ndarray, ThrustSensitivity]:
        """:meth:`virtual_sensitivity` on the rows of :meth:`input_profile`: its times and
        the sensitivity (here the commands' own rows)."""
        return np.asarray(cmd_t, dtype=float), self.virtual_sensitivity(duty_pct, clamp=clamp)

    def virtual_sensitivity(self, duty_pct: np.ndarray, clamp: bool = False
                            ) -> ThrustSensitivity:  # pragma: no cover
        raise NotImplementedError

    def duty_range(self) -> tuple[float, float]:
        """The open duties every thruster accepts, %: the tables' common range (0..100 for
        a layout of on/off valves only)."""
        ranges = [t.duty_range for t in self.tables()] or [(0.0, 100.0)]
        return max(r[0] for r in ranges), min(r[1] for r in ranges)

    def extent_m(self) -> float:  # pragma: no cover
        """The farthest thruster from the tracked origin, m."""
        raise NotImplementedError

    def tables(self) -> tuple[ThrustTable, ...]:  # pragma: no cover
        """Every thrust table the layout uses (for duty-range checks)."""
        raise NotImplementedError
