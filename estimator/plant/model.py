"""Planar rigid-body plant of a TPODS module on an air table.

State ``s = (x, y, psi, u, v, r)``: lab-frame position (m) and yaw (rad), body-frame
velocities (m/s) and yaw rate (rad/s). Inputs: the four thruster forces
``T = (T1, T2, T3, T4)`` in newtons. Parameters: mass (kg), Izz (kg m^2), moment arm
d (m), viscous friction ``ct`` (N s/m) and ``cr`` (N m s/rad), translation-induced
yaw torque ``kb`` (N m s/m) and a constant lab-frame tilt acceleration ``(ax, ay)``
(m/s^2).

Kinematics are the physically consistent form (the paper's Eqs. 1-2 omit the
rotation from body to lab frame)::

    xdot = u cos(psi) - v sin(psi)        ydot = u sin(psi) + v cos(psi)
    psidot = r
    udot = Fx/m + r v + ( ax cos psi + ay sin psi)
    vdot = Fy/m - r u + (-ax sin psi + ay cos psi)
    rdot = Mz/Izz
    Fx = (T2 + T3 - T1 - T4)/sqrt(2) - ct u
    Fy = (T1 + T2 - T3 - T4)/sqrt(2) - ct v
    Mz = d (T1 + T3 - T2 - T4) - cr r + kb sqrt(u^2 + v^2)

All array functions broadcast over leading dimensions: ``s`` has shape (..., 6),
``thrust_n`` (..., 4) and every parameter is a scalar or an array broadcastable
to the leading shape. This lets the Monte Carlo propagate many runs at once.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from functools import cache, lru_cache
from typing import Any

import numpy as np

from common.constants import ARM_M  # noqa: F401  (re-exported: the plant's nominal arm)
from estimator.plant.segments import segment_thrust, zoh_segments

STATE_NAMES = ("x", "y", "psi", "u", "v", "r")
PARAM_NAMES = ("mass", "izz", "ct", "cr", "kb", "ax", "ay", "cx", "cy")
"""Parameters that :func:`jac_params` can differentiate with respect to. ``cx, cy`` (m): the
centre of mass in the body frame of the tracked frame (a structure; 0 for a module tracked
at its centre of mass)."""


SQRT1_2 = math.sqrt(0.5)


@dataclass(frozen=True)
class PlantParams:
    """Physical parameters of the plant (SI units)."""

    mass_kg: float
    izz_kgm2: float
    arm_m: float = ARM_M
    ct: float = 0.0
    cr: float = 0.0
    kb: float = 0.0
    ax: float = 0.0
    ay: float = 0.0
    cx: float = 0.0
    cy: float = 0.0

    def kwargs(self) -> dict[str, float]:
        """Keyword arguments for the array functions of this module."""
        d = asdict(self)
        return {"mass": d.pop("mass_kg"), "izz": d.pop("izz_kgm2"), "arm": d.pop("arm_m"), **d}

    @property
    def has_friction(self) -> bool:
        return any(v != 0.0 for v in (self.ct, self.cr, self.kb, self.ax, self.ay))

    @property
    def com_offset(self) -> bool:
        """The tracked frame is not at the centre of mass (cx or cy non-zero)."""
        return self.cx != 0.0 or self.cy != 0.0


def wrench(thrust_n: np.ndarray, arm: float = ARM_M) -> np.ndarray:
    """Thruster-only body force and moment ``(Fx, Fy, Mz)``, shape (..., 3), N and N m."""
    t = np.asarray(thrust_n, dtype=float)
    t1, t2, t3, t4 = t[..., 0], t[..., 1], t[..., 2], t[..., 3]
    lead = t.shape[:-1] if isinstance(arm, (float, int)) else np.broadcast_shapes(
        t.shape[:-1], np.shape(arm))
    out = np.empty(lead + (3,))
    out[..., 0] = (t2 + t3 - t1 - t4) * SQRT1_2
    out[..., 1] = (t1 + t2 - t3 - t4) * SQRT1_2
    out[..., 2] = arm * (t1 + t3 - t2 - t4)
    return out


# --------------------------------------------------------------------------------------
# The plant, written once.
#
# Every effect adds terms to the state derivative and gives their partial derivatives
# (analytic Jacobians) with respect to the states and to the parameters it involves.
# The terms are Python expressions in these symbols:
#
#   u, v, r       body velocities and yaw rate      c, sn      cos(psi), sin(psi)
#   fx, fy, mz    thruster wrench (:func:`wrench`)  im, ii     1/mass, 1/Izz
#   sp            speed hypot(u, v)                 usp, vsp   u/sp, v/sp (0 at rest)
#   ct, cr, kb, ax, ay   the parameters of PARAM_NAMES
#
# From this one table the module compiles (once per set of effects and estimated
# parameters, cached) every form the consumers need: array functions for any leading
# shape (:func:`dynamics`, :func:`jac_state`, :func:`jac_params`, the Monte Carlo and the
# vectorised filter), the scalar stage function of the lean filter and the fused scalar
# RK4 loop of the simulator and batch least squares (the expressions inlined: a Python
# call per RK4 stage would double the cost of the batch fit). A new disturbance is one
# more entry here.

_SYMBOLS = ("u", "v", "r", "c", "sn", "fx", "fy", "mz", "im", "ii", "sp", "usp", "vsp",
            "ct", "cr", "kb", "ax", "ay", "cx", "cy")
_VARYING = frozenset(("u", "v", "r", "c", "sn", "sp", "usp", "vsp"))
"""Symbols that change within a hold segment (the others are constant over a segment)."""
_COLS = ("psi", "u", "v", "r")
"""States the derivative depends on (x and y do not enter it)."""


@dataclass(frozen=True)
class Effect:
    """One physical effect of the plant.

    Attributes:
        name: what it is.
        params: the parameters it brings; the effect is left out of the compiled code
            while all of them are zero and none is estimated.
        rates: state name -> its term in that state's derivative.
        partials: (state, state or parameter name) -> partial derivative of that term.
        speed: the terms use ``sp``, ``usp`` or ``vsp``.
    """

    name: str
    params: tuple[str, ...]
    rates: Mapping[str, str]
    partials: Mapping[tuple[str, str], str]
    speed: bool = False


EFFECTS: tuple[Effect, ...] = (
    Effect("kinematics (body velocities rotated into the lab frame)", (),
           {"x": "u * c - v * sn", "y": "u * sn + v * c", "psi": "r"},
           {("x", "psi"): "-u * sn - v * c", ("x", "u"): "c", ("x", "v"): "-sn",
            ("y", "psi"): "u * c - v * sn", ("y", "u"): "sn", ("y", "v"): "c",
            ("psi", "r"): "1.0"}),
    Effect("thrusters (wrench of the four nozzles)", (),
           {"u": "fx * im", "v": "fy * im", "r": "mz * ii"},
           {("u", "mass"): "-fx * im * im", ("v", "mass"): "-fy * im * im",
            ("r", "izz"): "-mz * ii * ii"}),
    Effect("rigid body in a rotating frame", (),
           {"u": "r * v", "v": "-r * u"},
           {("u", "v"): "r", ("u", "r"): "v", ("v", "u"): "-r", ("v", "r"): "-u"}),
    Effect("viscous friction", ("ct", "cr"),
           {"u": "-ct * u * im", "v": "-ct * v * im", "r": "-cr * r * ii"},
           {("u", "u"): "-ct * im", ("u", "mass"): "ct * u * im * im", ("u", "ct"): "-u * im",
            ("v", "v"): "-ct * im", ("v", "mass"): "ct * v * im * im", ("v", "ct"): "-v * im",
            ("r", "r"): "-cr * ii", ("r", "izz"): "cr * r * ii * ii", ("r", "cr"): "-r * ii"}),
    Effect("yaw torque from translation (ball transfers)", ("kb",),
           {"r": "kb * sp * ii"},
           {("r", "u"): "kb * usp * ii", ("r", "v"): "kb * vsp * ii",
            ("r", "izz"): "-kb * sp * ii * ii", ("r", "kb"): "sp * ii"}, speed=True),
    Effect("table tilt (constant lab-frame acceleration)", ("ax", "ay"),
           {"u": "ax * c + ay * sn", "v": "-ax * sn + ay * c"},
           {("u", "psi"): "-ax * sn + ay * c", ("v", "psi"): "-ax * c - ay * sn",
            ("u", "ax"): "c", ("u", "ay"): "sn", ("v", "ax"): "-sn", ("v", "ay"): "c"}),
    # the thrust moment is about the tracked origin; about the centre of mass c it is
    # Mz - c x F (the states are the centre of mass's; the poses are the tracked frame's,
    # see :func:`tracked_pose`)
    Effect("centre of mass off the tracked origin (moment of the thrust about it)", ("cx", "cy"),
           {"r": "(cy * fx - cx * fy) * ii"},
           {("r", "cx"): "-fy * ii", ("r", "cy"): "fx * ii",
            ("r", "izz"): "-(cy * fx - cx * fy) * ii * ii"}),
)

ALL_EFFECTS = tuple(range(len(EFFECTS) - 1))
"""Every effect of a module tracked at its centre of mass (what the filters compile)."""
EVERY_EFFECT = tuple(range(len(EFFECTS)))
"""Every effect, the centre-of-mass offset included."""


def _nonzero(v) -> bool:
    """``v`` (a number or an array) is non-zero somewhere (a plain number without numpy:
    the array functions ask this for every call)."""
    if isinstance(v, (float, int)):
        return bool(v != 0)
    return bool(np.any(np.asarray(v) != 0))


def active_effects(values: Mapping[str, Any], names: Sequence[str] = ()) -> tuple[int, ...]:
    """Indices of the effects needed for parameter ``values`` when ``names`` are estimated."""
    out = []
    for i, e in enumerate(EFFECTS):
        if not e.params or any(p in names or _nonzero(values.get(p, 0.0)) for p in e.params):
            out.append(i)
    return tuple(out)


def _sum(terms: list[str]) -> str:
    return " + ".join(f"({t})" for t in terms) if terms else "0.0"


def _rate_exprs(effects) -> list[str]:
    return [_sum([EFFECTS[i].rates[s] for i in effects if s in EFFECTS[i].rates])
            for s in STATE_NAMES]


def jacobian_pattern(effects, names: Sequence[str]) -> tuple[tuple[int, int], ...]:
    """Non-zero ``(row, column)`` entries of the augmented Jacobian, row-major.

    Rows are the six states, columns the six states followed by ``names``.
    """
    cols = STATE_NAMES + tuple(names)
    pos = {(STATE_NAMES.index(s), cols.index(q)) for i in effects
           for (s, q) in EFFECTS[i].partials if q in cols}
    return tuple(sorted(pos))


def _jac_exprs(effects, names) -> list[str]:
    cols = STATE_NAMES + tuple(names)
    return [_sum([EFFECTS[k].partials[(STATE_NAMES[i], cols[j])] for k in effects
                  if (STATE_NAMES[i], cols[j]) in EFFECTS[k].partials])
            for i, j in jacobian_pattern(effects, names)]


def _uses_speed(effects) -> bool:
    return any(EFFECTS[i].speed for i in effects)


_ARGS = "psi, u, v, r, fx, fy, mz, mass, izz, ct, cr, kb, ax, ay"
_OPT = "cx=0.0, cy=0.0"  # keyword-compatible: callers without a centre-of-mass offset omit them
_NS = {"cos": math.cos, "sin": math.sin, "hypot": math.hypot, "np": np}


def _compile(src: str, name: str):
    ns = dict(_NS)
    exec(compile(src, f"<plant {name}>", "exec"), ns)  # noqa: S102 -- code built from EFFECTS
    fn = ns[name]
    fn.source = src
    return fn


@cache
def array_function(effects: tuple[int, ...], names: tuple[str, ...] | None):
    """``f(psi, u, v, r, fx, fy, mz, mass, izz, ct, cr, kb, ax, ay)`` on arrays of any
    broadcastable shapes: the six state derivatives, and with ``names`` given (not None)
    also the Jacobian entries of :func:`jacobian_pattern` (a tuple each)."""
    lines = [f"def f({_ARGS}, {_OPT}):", "    c = np.cos(psi)", "    sn = np.sin(psi)",
             "    im = 1.0 / mass", "    ii = 1.0 / izz"]
    if _uses_speed(effects):
        lines.append("    sp = np.hypot(u, v)")
        if names is not None:
            lines += ["    pos = sp > 0", "    safe = np.where(pos, sp, 1.0)",
                      "    usp = np.where(pos, u / safe, 0.0)",
                      "    vsp = np.where(pos, v / safe, 0.0)"]
    rates = ", ".join(_rate_exprs(effects))
    if names is None:
        lines.append(f"    return ({rates})")
    else:
        lines.append(f"    return ({rates}), ({', '.join(_jac_exprs(effects, names))},)")
    return _compile("\n".join(lines) + "\n", "f")


@cache
def scalar_stage(effects: tuple[int, ...], names: tuple[str, ...]):
    """``f(psi, u, v, r, fx, fy, mz, mass, izz, ct, cr, kb, ax, ay, vals)`` on floats: returns
    the six state derivatives and appends the Jacobian entries of :func:`jacobian_pattern`
    to the list ``vals`` (one RK4 stage of the lean filter)."""
    lines = [f"def f({_ARGS}, vals, {_OPT}):", "    c = cos(psi)", "    sn = sin(psi)",
             "    im = 1.0 / mass", "    ii = 1.0 / izz"]
    if _uses_speed(effects):
        lines += ["    sp = hypot(u, v)", "    usp = u / sp if sp > 0.0 else 0.0",
                  "    vsp = v / sp if sp > 0.0 else 0.0"]
    lines.append(f"    vals += ({', '.join(_jac_exprs(effects, names))},)")
    lines.append(f"    return ({', '.join(_rate_exprs(effects))})")
    return _compile("\n".join(lines) + "\n", "f")


_IDENT = re.compile(r"[A-Za-z_]\w*")


@cache
def scalar_rk4_chain(effects: tuple[int, ...], substeps: bool):
    """The fused scalar RK4 loop over hold segments, compiled for ``effects``.

    ``f(state, dts, w, mass, izz, ct, cr, kb, ax, ay[, nsub])`` -> list of the states
    (6-tuples) at the end of every segment: ``dts`` segment lengths, ``w`` their wrenches
    (3-sequences), ``nsub`` RK4 steps per segment (without ``substeps``: one step each).
    Terms constant over a segment (thrust over mass, ...) are evaluated once per segment.
    """
    rates = _rate_exprs(effects)
    hoisted: dict[str, str] = {}

    def hoist(expr: str) -> str:
        # split a sum of parenthesised terms and move the segment-constant ones out
        terms = expr[1:-1].split(") + (") if expr != "0.0" else []
        out = []
        for t in terms:
            if set(_IDENT.findall(t)) & _VARYING:
                out.append(f"({t})")
            else:
                key = hoisted.setdefault(t, f"g{len(hoisted)}")
                out.append(key)
        return " + ".join(out) if out else "0.0"

    body = [hoist(e) for e in rates]
    speed = _uses_speed(effects)
    ind = "            " if substeps else "        "
    stage = []
    for k in range(1, 5):
        if k == 1:
            stage.append(f"{ind}psi = PS\n{ind}u = U\n{ind}v = V\n{ind}r = R")
        else:
            f = "h2" if k < 4 else "h"
            stage.append(f"{ind}psi = PS + {f} * k{k - 1}_2\n{ind}u = U + {f} * k{k - 1}_3\n"
                         f"{ind}v = V + {f} * k{k - 1}_4\n{ind}r = R + {f} * k{k - 1}_5")
        stage.append(f"{ind}c = cos(psi)\n{ind}sn = sin(psi)")
        if speed:
            stage.append(f"{ind}sp = hypot(u, v)")
        stage += [f"{ind}k{k}_{i} = {e}" for i, e in enumerate(body)]
    upd = "\n".join(f"{ind}{S} += h6 * (k1_{i} + 2 * k2_{i} + 2 * k3_{i} + k4_{i})"
                    for i, S in enumerate(("X", "Y", "PS", "U", "V", "R")))
    seg = "\n".join(f"        {g} = {t}" for t, g in hoisted.items())
    head = ("def f(state, dts, w, mass, izz, ct, cr, kb, ax, ay, nsub=None, cx=0.0, cy=0.0):\n"
            "    im = 1.0 / mass\n    ii = 1.0 / izz\n"
            "    X, Y, PS, U, V, R = (float(a) for a in state)\n"
            "    rows = [None] * len(dts)\n")
    if substeps:
        loop = ("    for i, (dt, (fx, fy, mz), n) in enumerate(zip(dts, w, nsub)):\n"
                f"{seg}\n        h = dt / n if n else 0.0\n        h2 = 0.5 * h\n"
                "        h6 = h / 6.0\n        for _ in range(n):\n")
    else:
        loop = ("    for i, (h, (fx, fy, mz)) in enumerate(zip(dts, w)):\n"
                f"{seg}\n        h2 = 0.5 * h\n        h6 = h / 6.0\n")
    src = (head + loop + "\n".join(stage) + "\n" + upd + "\n"
           "        rows[i] = (X, Y, PS, U, V, R)\n    return rows\n")
    return _compile(src, "f")


def _present(ct, cr, kb, ax, ay, cx, cy, names) -> tuple[int, ...]:
    """:func:`active_effects` of these parameter values with ``names`` estimated: an effect
    whose parameters are all zero and not estimated adds exact zeros, so it is left out."""
    key = (ct, cr, kb, ax, ay, cx, cy)
    if all(type(v) is float for v in key):  # plain numbers: the same answer as last time
        return _present_numbers(key, tuple(names))
    return active_effects(dict(zip(_OPTIONAL, key, strict=True)), names)


_OPTIONAL = ("ct", "cr", "kb", "ax", "ay", "cx", "cy")
"""The parameters whose effects are left out while they are zero and not estimated."""


@lru_cache(maxsize=256)
def _present_numbers(key: tuple[float, ...], names: tuple[str, ...]) -> tuple[int, ...]:
    return active_effects(dict(zip(_OPTIONAL, key, strict=True)), names)


def dynamics(s, thrust_n, mass, izz, arm=ARM_M, ct=0.0, cr=0.0, kb=0.0, ax=0.0, ay=0.0,
             cx=0.0, cy=0.0):
    """State derivative ``sdot``, shape (..., 6)."""
    s = np.asarray(s, dtype=float)
    w = wrench(thrust_n, arm)
    f = array_function(_present(ct, cr, kb, ax, ay, cx, cy, ()), None)
    rates = f(s[..., 2], s[..., 3], s[..., 4], s[..., 5], w[..., 0], w[..., 1], w[..., 2],
              mass, izz, ct, cr, kb, ax, ay, cx, cy)
    same = s.shape[:-1] == w.shape[:-1] and s.shape[-1:] == (6,)
    out = np.empty(s.shape if same else np.broadcast_shapes(s.shape, w.shape[:-1] + (6,)))
    for i, v in enumerate(rates):
        out[..., i] = v
    return out


def _jac(s, thrust_n, mass, izz, arm, ct, cr, kb, ax, ay, cx, cy, names, cols):
    s = np.asarray(s, dtype=float)
    w = wrench(thrust_n, arm)
    lead = np.broadcast_shapes(s.shape[:-1], w.shape[:-1], np.shape(mass), np.shape(izz))
    eff = _present(ct, cr, kb, ax, ay, cx, cy, names)
    f = array_function(eff, names)
    _, vals = f(s[..., 2], s[..., 3], s[..., 4], s[..., 5], w[..., 0], w[..., 1], w[..., 2],
                mass, izz, ct, cr, kb, ax, ay, cx, cy)
    J = np.zeros(lead + (6, len(cols)))
    for (i, j), v in zip(jacobian_pattern(eff, names), vals, strict=True):
        if j in cols:
            J[..., i, cols[j]] = v
    return J


def jac_state(s, thrust_n, mass, izz, arm=ARM_M, ct=0.0, cr=0.0, kb=0.0, ax=0.0, ay=0.0,
              cx=0.0, cy=0.0):
    """Analytic ``df/ds``, shape (..., 6, 6).

    The ``kb*sqrt(u^2+v^2)`` term is not differentiable at zero speed; its
    derivative is taken as 0 there (the one-sided limits average to 0).
    """
    return _jac(s, thrust_n, mass, izz, arm, ct, cr, kb, ax, ay, cx, cy, (),
                {j: j for j in range(6)})


def jac_params(s, thrust_n, mass, izz, arm=ARM_M, ct=0.0, cr=0.0, kb=0.0, ax=0.0, ay=0.0,
               cx=0.0, cy=0.0, names: tuple[str, ...] = ("mass", "izz")):
    """Analytic ``df/dtheta`` for the parameters ``names`` (from PARAM_NAMES), shape (..., 6, p)."""
    names = tuple(names)
    for n in names:
        if n not in PARAM_NAMES:
            raise ValueError(f"unknown parameter {n!r}; choose from {PARAM_NAMES}")
    return _jac(s, thrust_n, mass, izz, arm, ct, cr, kb, ax, ay, cx, cy, names,
                {6 + j: j for j in range(len(names))})


def rk4_hold_chain(s0, dts, w, params: PlantParams, nsub=None) -> list[tuple]:
    """Fused scalar RK4 over hold segments (see :func:`scalar_rk4_chain`): the states at the
    end of every segment. ``w`` (M, 3) wrenches; ``nsub`` (M,) steps per segment (default 1)."""
    p = params
    eff = active_effects({"ct": p.ct, "cr": p.cr, "kb": p.kb, "ax": p.ax, "ay": p.ay,
                          "cx": p.cx, "cy": p.cy})
    dts = dts.tolist() if isinstance(dts, np.ndarray) else list(dts)
    w = w.tolist() if isinstance(w, np.ndarray) else list(w)
    args = (p.mass_kg, p.izz_kgm2, p.ct, p.cr, p.kb, p.ax, p.ay)
    com = {"cx": p.cx, "cy": p.cy} if p.com_offset else {}
    if nsub is None:
        return scalar_rk4_chain(eff, False)(s0, dts, w, *args, **com)
    nsub = nsub.tolist() if isinstance(nsub, np.ndarray) else list(nsub)
    return scalar_rk4_chain(eff, True)(s0, dts, w, *args, nsub, **com)


def integrate_zoh(s0, cmd_t, thrust_n, t_out, params: PlantParams, max_step: float = 1 / 480):
    """Integrate the plant under zero-order-hold thrusts, never stepping across a switch.

    Args:
        s0: initial state (6,) at ``t_out[0]``.
        cmd_t: (Nc,) increasing switch times, s; row j of ``thrust_n`` holds on
            ``[cmd_t[j], cmd_t[j+1])``; before ``cmd_t[0]`` thrust is zero.
        thrust_n: (Nc, 4) thruster forces, N.
        t_out: (N,) non-decreasing output times, s.
        params: plant parameters.
        max_step: largest RK4 step, s. The default gives < 1e-9 m error over
            120 s for the TPODS accelerations.

    Returns:
        (N, 6) states at ``t_out``; psi is continuous (not wrapped).
    """
    events, cmd_idx, out_pos = zoh_segments(cmd_t, t_out)
    w = wrench(segment_thrust(thrust_n, cmd_idx), params.arm_m)
    dts = np.diff(events)
    nsub = np.where(dts > 0, np.maximum(1, np.ceil(dts / max_step - 1e-9)), 0).astype(int)
    states = np.empty((len(events), 6))
    states[0] = [float(a) for a in s0]
    rows = rk4_hold_chain(states[0], dts, w, params, nsub)
    if rows:
        states[1:] = rows
    return states[out_pos]


def wrap_angle(a):
    """Wrap angles to (-pi, pi]."""
    a = np.asarray(a, dtype=float)
    w = np.mod(a + np.pi, 2 * np.pi) - np.pi
    return np.where(w == -np.pi, np.pi, w)
