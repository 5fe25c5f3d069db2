"""argparse value types shared by the sub-commands (each raises a one-line error)."""

from __future__ import annotations

import argparse
import math


def positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(v) or v <= 0:
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text!r}")
    return v


def float_between(lo: float, hi: float, unit: str = ""):
    """An argparse type for a number in ``[lo, hi]`` (a plausibility range: a value outside
    it is a typo or a unit mistake, and the numerics would overflow before saying so)."""
    u = f" {unit}" if unit else ""

    def parse(text: str) -> float:
        v = positive_float(text) if lo > 0 else nonneg_float(text)
        if not lo <= v <= hi:
            raise argparse.ArgumentTypeError(f"must lie in {lo:g}..{hi:g}{u}, got {text!r}")
        return v

    return parse


SIGMA_POS_M = float_between(1e-6, 1.0, "m")
"""A pose position noise, m: 1 um (a laboratory interferometer) to 1 m (not motion capture)."""
SIGMA_YAW_DEG = float_between(1e-4, 90.0, "deg")
MASS_KG = float_between(1e-3, 1e4, "kg")
"""A body on an air table, kg: from a gram to ten tonnes."""
IZZ_KGM2 = float_between(1e-8, 1e5, "kg m^2")


def nonneg_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(v) or v < 0:
        raise argparse.ArgumentTypeError(f"must be a non-negative number, got {text!r}")
    return v


def int_at_least(lo: int):
    """An argparse type for a whole number >= ``lo``."""
    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
        if v < lo:
            raise argparse.ArgumentTypeError(f"must be a whole number >= {lo}, got {text!r}")
        return v
    parse.__name__ = f"whole number >= {lo}"  # argparse names the type in its error line
    return parse


def fraction(text: str) -> float:
    v = nonneg_float(text)
    if v >= 1:
        raise argparse.ArgumentTypeError(f"must lie in [0, 1), got {text!r}")
    return v


def float_list(n: int | None = None):
    """Comma-separated floats, optionally exactly ``n`` of them."""

    def parse(text: str) -> list[float]:
        try:
            vals = [float(x) for x in text.split(",") if x.strip()]
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None
        if n is not None and len(vals) != n:
            raise argparse.ArgumentTypeError(f"expected {n} comma-separated numbers, got {text!r}")
        if not all(math.isfinite(v) for v in vals):
            raise argparse.ArgumentTypeError(f"numbers must be finite, got {text!r}")
        return vals

    return parse


def parse_time_window(text: str | None) -> tuple[float | None, float | None]:
    """``"T0:T1"`` in seconds, either side may be empty (the documented form; ``"T0,T1"``
    is read the same) -> ``(t0, t1)``; ``(None, None)`` for None or ''. A ValueError
    names what is wrong (not two numbers, or an end that does not follow its start)."""
    if text is None or text.strip() == "":
        return None, None
    sep = ":" if ":" in text else ","
    parts = text.split(sep)
    if len(parts) != 2:
        raise ValueError(f"window must be T0:T1 (seconds), got {text!r}")
    try:
        t0, t1 = (float(p) if p.strip() else None for p in parts)
    except ValueError:
        raise ValueError(f"window must be T0:T1 (seconds), got {text!r}") from None
    if any(v is not None and not math.isfinite(v) for v in (t0, t1)):
        raise ValueError(f"window must be T0:T1 (seconds), got {text!r}")
    if t0 is not None and t1 is not None and t1 <= t0:
        raise ValueError(f"window end must follow its start, got {text!r}")
    return t0, t1


def time_window(text: str) -> tuple[float | None, float | None]:
    """argparse type for ``--window T0:T1`` (or ``T0,T1``); see :func:`parse_time_window`."""
    try:
        return parse_time_window(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


SEED_MAX = 2**32 - 1


def random_seed(text: str) -> int:
    """argparse type for ``--seed``: a whole number in 0..2**32-1 (what every random
    generator of the toolkit accepts; numpy refuses negative seeds)."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a whole number in 0..{SEED_MAX}, got {text!r}") from None
    if not 0 <= v <= SEED_MAX:
        raise argparse.ArgumentTypeError(f"must be a whole number in 0..{SEED_MAX}, got {text!r}")
    return v


class VehicleFile(str):
    """The path of ``--vehicle FILE``: a str that says it names a vehicle.toml. The option
    shares ``args.structure`` with ``--structure`` (a vehicle goes wherever a structure
    goes); :func:`common.vehicle.load_layout` reads it as a vehicle."""


def vehicle_file(text: str) -> VehicleFile:
    """argparse type of ``--vehicle``."""
    return VehicleFile(text)


INITIAL_KEYS = {"m": "mass", "mass": "mass", "izz": "izz", "ct": "ct", "cr": "cr", "kb": "kb",
                "ax": "ax", "ay": "ay", "x": "x", "y": "y", "psi": "psi", "u": "u", "v": "v",
                "r": "r", "arm": "arm", "cx": "cx", "cy": "cy"}
"""The names of an initial guess or a fixed value (``--initial``, ``--fixed``): what each means."""
AT_KEYS = {"m": "mass", "mass": "mass", "izz": "izz", "cx": "cx", "cy": "cy", "delay": "delay",
           "drop": "drop"}
"""The names of the point of a vehicle's joint bound (``--at``)."""


def key_values(text: str, keys: dict[str, str] | None = None) -> dict[str, float]:
    """``"m=1,izz=0.005"`` -> {"mass": 1.0, "izz": 0.005} (argparse type); ``keys`` the
    accepted names and what each means (default the initial-guess names)."""
    keys = INITIAL_KEYS if keys is None else keys
    out: dict[str, float] = {}
    for item in text.split(","):
        item = item.strip()
        if not item:
            continue
        if "=" not in item:
            raise argparse.ArgumentTypeError(f"expected NAME=VALUE items, got {item!r}")
        k, v = (s.strip() for s in item.split("=", 1))
        if k.lower() not in keys:
            raise argparse.ArgumentTypeError(f"unknown name {k!r}{nearest(k, keys)}; use "
                                             f"{', '.join(sorted(set(keys)))}")
        val = _finite_float(v, f"not a number: {v!r} (for {k})", f"{k} must be finite")
        _check_range(keys[k.lower()], val)
        out[keys[k.lower()]] = val
    return out


def _check_range(name: str, val: float) -> None:
    """The ranges vehicle.toml enforces, for a value given on the command line
    (:mod:`common.plausible_inputs`; a drop's upper bound needs the vehicle: checked where
    it is known)."""
    from common.errors import UserError
    from common.plausible_inputs import check_positive, check_time_s

    try:
        if name in ("mass", "izz"):
            check_positive(val, name)
        elif name == "delay":
            check_time_s(val, name)
        elif name == "drop" and val < 0:
            raise UserError(f"drop must be >= 0, got {val:g}")
    except UserError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def at_values(text: str) -> dict[str, float]:
    """``--at mass=23,delay=0.03``: the point of a vehicle's joint bound (argparse type)."""
    return key_values(text, AT_KEYS)


def nearest(name: str, choices) -> str:
    """`` (did you mean X?)`` for the closest of ``choices``, or ''."""
    import difflib

    close = difflib.get_close_matches(name.lower(), [c.lower() for c in choices], n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _finite_float(text: str, not_number: str, not_finite: str) -> float:
    """``float(text)``, finite, else an argparse error with the message given."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(not_number) from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(not_finite)
    return v


def clock_offset_arg(text: str) -> str | float:
    """``auto``, ``none`` or a number of ms (a float; finite)."""
    if text.strip().lower() in ("auto", "none"):
        return text.strip().lower()
    return _finite_float(text, f"must be auto, none or a number of ms, got {text!r}",
                         f"must be auto, none or a finite number of ms, got {text!r}")
