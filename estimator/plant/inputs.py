"""Thruster input sequences (duty percent per valve) for simulation and play-back.

Every generator returns ``(t, duty_pct)`` with ``t`` (N,) seconds and ``duty_pct``
(N, 4) percent, sampled at ``cmd_rate_hz`` and held (zero-order hold). A final
all-closed row at ``t = duration`` marks the end of the commanded span.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from common.errors import UserError
from common.plausible import check_duty_rows
from common.runfolder import COMMAND_COLUMNS, read_table_lines
from common.runwriter import command_columns

INPUT_NAMES = ("phase-sine", "translate-rotate", "pulses", "pulse-groups")
PULSE_S = 0.5
"""Open time of each valve in the ``pulses`` input, s (then as long closed)."""


def _grid(duration_s: float, cmd_rate_hz: float) -> np.ndarray:
    if duration_s <= 0:
        raise UserError(f"duration must be positive, got {duration_s:g} s")
    if cmd_rate_hz <= 0:
        raise UserError(f"command rate must be positive, got {cmd_rate_hz:g} Hz")
    n = int(math.floor(duration_s * cmd_rate_hz + 1e-9))
    t = np.arange(n + 1) / cmd_rate_hz
    return t[t < duration_s - 1e-12]


def _close(t: np.ndarray, duty: np.ndarray, duration_s: float) -> tuple[np.ndarray, np.ndarray]:
    return np.append(t, duration_s), np.vstack([duty, np.zeros((1, duty.shape[1]))])


def phase_sine(duration_s: float, cmd_rate_hz: float = 50.0, amplitude_pct: float = 20.0,
               omega_rad_s: float = 1.0, mean_pct: float = 50.0,
               phases_rad: tuple[float, ...] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The paper's informed input: d_i(t) = mean + A sin(w t + phase_i), phase_i = (i-1) pi/4."""
    t = _grid(duration_s, cmd_rate_hz)
    ph = np.arange(4) * math.pi / 4 if phases_rad is None else np.asarray(phases_rad, float)
    duty = mean_pct + amplitude_pct * np.sin(omega_rad_s * t[:, None] + ph[None, :])
    return _close(t, duty, duration_s)


def translate_rotate(duration_s: float, cmd_rate_hz: float = 50.0, translate_pct: float = 25.0,
                     rotate_pct: float = 15.0) -> tuple[np.ndarray, np.ndarray]:
    """The paper's experiment input, a 14 s cycle.

    0-7 s: y-translation square wave of period 2 s (valves 1,2 then 3,4 at ``translate_pct``);
    7-14 s: yaw square wave of period 1 s (valves 1,3 then 2,4 at ``rotate_pct``).
    """
    t = _grid(duration_s, cmd_rate_hz)
    tc = np.mod(t + 1e-9, 14.0)
    duty = np.zeros((len(t), 4))
    trans = tc < 7.0
    first_half = np.where(trans, np.mod(tc, 2.0) < 1.0, np.mod(tc - 7.0, 1.0) < 0.5)
    # translation: +y with valves 1,2, -y with valves 3,4
    duty[trans & first_half] = [translate_pct, translate_pct, 0, 0]
    duty[trans & ~first_half] = [0, 0, translate_pct, translate_pct]
    # rotation: +yaw with valves 1,3, -yaw with valves 2,4
    duty[~trans & first_half] = [rotate_pct, 0, rotate_pct, 0]
    duty[~trans & ~first_half] = [0, rotate_pct, 0, rotate_pct]
    return _close(t, duty, duration_s)


def pulses(duration_s: float, n_channels: int, pulse_s: float = PULSE_S,
           duty_pct: float = 100.0) -> tuple[np.ndarray, np.ndarray]:
    """An on/off input for any number of valves: valve i (from 1) opens at ``duty_pct``
    (100: fully open) for ``pulse_s``, then all stay closed for ``pulse_s``, then valve
    i + 1, cycling. Each valve's force and moment show alone (mass, Izz and the centre of
    mass separate); the switch times are exact multiples of ``pulse_s``."""
    if duration_s <= 0:
        raise UserError(f"duration must be positive, got {duration_s:g} s")
    t = np.arange(int(math.ceil(duration_s / pulse_s - 1e-9))) * pulse_s
    duty = np.zeros((len(t), n_channels))
    slot = np.arange(len(t))
    on = slot % 2 == 0
    duty[on, (slot[on] // 2) % n_channels] = duty_pct
    return _close(t, duty, duration_s)


GROUP_SIZES = (1, 2, 3)
"""Valves open together in the ``pulse-groups`` input, in turn."""


def pulse_groups(duration_s: float, n_channels: int, pulse_s: float = PULSE_S,
                 sizes: tuple[int, ...] = GROUP_SIZES, seed: int = 0
                 ) -> tuple[np.ndarray, np.ndarray]:
    """An on/off input that opens SEVERAL valves at once (what informs a shared supply's
    drop): like :func:`pulses` (open ``pulse_s``, then all closed ``pulse_s``), but pulse j
    opens ``sizes[j % len(sizes)]`` distinct valves drawn at random (fixed ``seed``: the
    same input every time)."""
    if duration_s <= 0:
        raise UserError(f"duration must be positive, got {duration_s:g} s")
    t = np.arange(int(math.ceil(duration_s / pulse_s - 1e-9))) * pulse_s
    duty = np.zeros((len(t), n_channels))
    rng = np.random.default_rng(seed)
    for j, row in enumerate(range(0, len(t), 2)):
        size = min(sizes[j % len(sizes)], n_channels)
        duty[row, rng.choice(n_channels, size, replace=False)] = 100.0
    return _close(t, duty, duration_s)


def from_commands_csv(path: str | Path, n_channels: int = 4,
                      valid_pct: tuple[float, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Read a commands.csv (run-folder format) as an input sequence: (N,) s and (N,
    n_channels) percent (``t,d1..d{n_channels}``: a structure's 4N channels). A duty
    outside 0..100 % (or an open one outside ``valid_pct``, a thrust table's valid range)
    is refused naming the file line."""
    from common.command_rules import columns_problem
    from common.csvtable import header_of

    v, lines = read_table_lines(Path(path), COMMAND_COLUMNS if n_channels == 4
                                else command_columns(n_channels))
    problem = columns_problem(header_of(Path(path)), n_channels,
                              "the TPODS module" if n_channels == 4 else "the layout")
    if problem is not None:
        raise UserError(f"{path}: {problem}")
    check_duty_rows(v[:, 1:], lines, path, valid_pct)
    return v[:, 0], v[:, 1:]


DEFAULT_DURATION_S = 120.0
END_TOLERANCE_S = 1e-3  # a file that ends this close to the asked duration is long enough


def make_input(spec: str, duration_s: float | None, cmd_rate_hz: float = 50.0,
               amplitude_pct: float = 20.0, omega_rad_s: float = 1.0,
               n_channels: int = 4, valid_pct: tuple[float, float] | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
    """Build an input by name (``phase-sine``, ``translate-rotate``) or from a commands.csv path.

    ``n_channels`` > 4 (a structure's 4N valves): the phase-sine's phase shifts continue
    across modules (channel i at (i-1) pi/4), a file needs ``d1..d{n_channels}``;
    ``translate-rotate`` is a single-module input and is refused; ``pulses`` (any number
    of channels: each valve fully open in turn, :func:`pulses`) and ``pulse-groups`` (1, 2,
    3 valves open at once, :func:`pulse_groups`) ignore ``cmd_rate_hz``.

    A file input is cut to ``duration_s`` (rows after it dropped, a closing row added);
    ``duration_s=None`` takes the whole file (and :data:`DEFAULT_DURATION_S` for a
    generated input). A file that ends before ``duration_s`` is a UserError naming both
    lengths (the run would silently be shorter than asked); ``valid_pct``: a thrust
    table's valid duty range the file's open duties must lie in (refused by line).
    """
    if duration_s is None and spec in INPUT_NAMES:
        duration_s = DEFAULT_DURATION_S
    if spec == "phase-sine":
        phases = None if n_channels == 4 else np.arange(n_channels) * math.pi / 4
        return phase_sine(duration_s, cmd_rate_hz, amplitude_pct, omega_rad_s, phases_rad=phases)
    if spec == "translate-rotate":
        if n_channels != 4:
            raise UserError("--input translate-rotate is the single module's input; a structure "
                            "takes phase-sine or a commands.csv with d1..d{4N}")
        return translate_rotate(duration_s, cmd_rate_hz)
    if spec == "pulses":
        return pulses(duration_s, n_channels)
    if spec == "pulse-groups":
        return pulse_groups(duration_s, n_channels)
    p = Path(spec)
    if p.is_dir():
        p = p / "commands.csv"
    if not p.exists():
        raise UserError(f"unknown input {spec!r}: choose {', '.join(INPUT_NAMES)} or a commands.csv path")
    t, d = from_commands_csv(p, n_channels, valid_pct)
    if duration_s is None:
        return t, d
    if t[-1] < duration_s - END_TOLERANCE_S:
        raise UserError(f"{p} holds {t[-1]:g} s of commands (t = {t[0]:g}..{t[-1]:g} s), less than "
                        f"--duration {duration_s:g} s: leave out --duration to use the whole file, "
                        f"or give --duration {t[-1]:g} or less")
    if t[-1] > duration_s:
        keep = t < duration_s
        t, d = _close(t[keep], d[keep], duration_s)
    return t, d
