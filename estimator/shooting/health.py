"""Thruster health: each thruster's efficiency (its thrust over the stated one) and a leak
while commanded closed, estimated from a whole run by segments, and a verdict per thruster.

With the mass unknown the efficiencies are identifiable only relative to each other (the
poses see thrust / mass): the fit holds the mass at a reference value and reports each
efficiency over the median of the thrusters' (``relative``). With the mass known
(``mass_kg``) they are absolute.

Verdicts, each needing a deviation both beyond the thresholds below and significant by a
likelihood-ratio test across segments (the fit repeated with the thruster held healthy:
efficiency at the reference, no leak; the cost difference divided by the parameter's
overdispersion, clustered over noise-only variance, so that misfit correlated within a
segment does not count as evidence; :data:`LR_LIMIT` ~ 3 sigma):

- ``dead``: efficiency below :data:`DEAD_BELOW`;
- ``reversed``: efficiency below -:data:`DEAD_BELOW` (pushes the other way);
- ``weak``: below 1 by more than :data:`WEAK_MIN_LOSS` and by more than twice the robust
  spread of the other thrusters' efficiencies (thrusters of one vehicle vary; a thruster
  is weak when it stands out from its peers);
- ``stuck-open``: a leak above :data:`LEAK_ABOVE` of its force while commanded closed. NOT
  tested yet: the fit estimates no leaks (with most valves closed most of the time, eight
  leaks are not separable from the three components of the wrench they add), so ``leak`` is
  0 and this verdict is never given;
- ``ok`` otherwise. ``resolution`` is the smallest loss the run resolves (3 sigma).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from common.vehicle import Vehicle
from estimator.shooting.fit import SegmentFit, fit_segments

DEAD_BELOW = 0.3
WEAK_MIN_LOSS = 0.03
LEAK_ABOVE = 0.2
LR_LIMIT = 9.0
BODY = ("mass", "izz", "cx", "cy", "ax", "ay", "ct", "cr", "delay")


@dataclass
class ThrusterHealth:
    name: str
    efficiency: float
    sigma: float
    leak: float
    leak_sigma: float
    verdict: str
    lr: float | None
    why: str

    def to_dict(self) -> dict:
        return {"name": self.name, "efficiency": self.efficiency, "sigma": self.sigma,
                "leak": self.leak, "leak_sigma": self.leak_sigma, "verdict": self.verdict,
                "lr_statistic": self.lr, "why": self.why}


@dataclass
class HealthReport:
    thrusters: list[ThrusterHealth]
    relative: bool
    reference_mass_kg: float
    fit: SegmentFit
    resolution: float

    def to_dict(self) -> dict:
        return {"relative": self.relative, "reference_mass_kg": self.reference_mass_kg,
                "resolution": self.resolution,
                "thrusters": [t.to_dict() for t in self.thrusters]}

    def lines(self) -> list[str]:
        what = ("relative to the median thruster (the mass is unknown)" if self.relative
                else f"absolute (mass {self.reference_mass_kg:g} kg)")
        out = [f"thruster health ({what}; {self.fit.plan.n} segments; smallest loss resolved "
               f"{self.resolution * 100:.1f} %):"]
        for t in self.thrusters:
            out.append(f"  {t.name:<6} efficiency {t.efficiency:6.3f} +- {t.sigma:.3f}: {t.verdict}"
                       + (f" ({t.why})" if t.why else ""))
        return out


def _health_names(vehicle: Vehicle, opens: np.ndarray, closes: np.ndarray, fixed) -> tuple:
    body = tuple(n for n in BODY if n != "mass" and n not in fixed)
    eff = tuple(f"eff.{t.name}" for i, t in enumerate(vehicle.thrusters) if opens[i])
    return body + eff


def thruster_health(pose_t, pose, vehicle: Vehicle, cmd_t, duty_pct, *,
                    mass_kg: float | None = None, initial: Mapping[str, float] | None = None,
                    fixed: Mapping[str, float] | None = None, sigma_pos_m: float = 0.01,
                    sigma_yaw_rad: float = math.radians(1.0), length_s: float | None = None,
                    exclude: Sequence[tuple[float, float]] = ()) -> HealthReport:
    """Efficiencies, leaks and verdicts of every thruster of a run (module doc)."""
    duty = np.asarray(duty_pct, float)
    opens = np.any(duty > 0, axis=0) & np.array([not t.dead for t in vehicle.thrusters])
    closes = np.any(duty <= 0, axis=0)
    from estimator.shooting.fit import start_values
    from estimator.shooting.inputs import vehicle_channels

    ch = vehicle_channels(vehicle, cmd_t, duty)
    initial = start_values(vehicle, pose_t, pose, ch, dict(initial or {}), dict(fixed or {}))
    ref = float(mass_kg if mass_kg is not None else initial["mass"])
    fixed = {**dict(fixed or {}), "mass": ref}
    names = _health_names(vehicle, opens, closes, fixed)
    kw = dict(fixed=fixed, initial={k: v for k, v in initial.items() if k != "mass"},
              sigma_pos_m=sigma_pos_m, sigma_yaw_rad=sigma_yaw_rad, exclude=exclude)
    fit = fit_segments(pose_t, pose, vehicle, cmd_t, duty, names=names, length_s=length_s, **kw)
    eff = {t.name: fit.values.get(f"eff.{t.name}", math.nan) for t in vehicle.thrusters}
    known = np.array([v for v in eff.values() if math.isfinite(v)])
    scale = float(np.median(known)) if mass_kg is None and len(known) else 1.0
    out = []
    for t in vehicle.thrusters:
        e = eff[t.name] / scale
        s = fit.sigma.get(f"eff.{t.name}", {}).get("total", math.nan) / abs(scale)
        lk = fit.values.get(f"leak.{t.name}", 0.0) / scale
        ls = fit.sigma.get(f"leak.{t.name}", {}).get("total", math.nan) / abs(scale)
        others = np.array([eff[o.name] / scale for o in vehicle.thrusters
                           if o.name != t.name and math.isfinite(eff[o.name])])
        spread = 1.4826 * float(np.median(np.abs(others - np.median(others)))) if len(others) > 2 else 0.0
        verdict, why = _verdict(e, s, lk, ls, spread, opens[vehicle.thrusters.index(t)])
        out.append(ThrusterHealth(t.name, e, s, lk, ls, verdict, None, why))
    _confirm(out, fit, pose_t, pose, vehicle, cmd_t, duty, names, scale, length_s, kw)
    sig = [t.sigma for t in out if math.isfinite(t.sigma)]
    resolution = 3.0 * float(np.median(sig)) if sig else math.nan
    return HealthReport(out, mass_kg is None, ref, fit, resolution)


def _verdict(e, s, leak, leak_s, spread, opened) -> tuple[str, str]:
    if not opened:
        return "ok", "never commanded open in this run: not tested"
    if e < -DEAD_BELOW and e + 3 * s < 0:
        return "reversed", "its thrust pushes the other way"
    if e < DEAD_BELOW and e + 3 * s < 1.0:
        return "dead", f"gives {max(e, 0) * 100:.0f} % of its stated thrust"
    if leak > LEAK_ABOVE and leak - 3 * leak_s > 0:
        return "stuck-open", f"pushes with {leak * 100:.0f} % of its force while commanded closed"
    loss = 1.0 - e
    if loss > max(WEAK_MIN_LOSS, 2 * spread, 3 * s):
        return "weak", f"{loss * 100:.0f} % below its stated thrust"
    return "ok", ""


def _confirm(report, fit, pose_t, pose, vehicle, cmd_t, duty, names, scale, length_s, kw):
    """The likelihood-ratio test of every verdict other than ok: the fit again with that
    thruster held healthy; a verdict the test does not confirm becomes ok, saying why."""
    for th in report:
        if th.verdict == "ok":
            continue
        hold = {f"eff.{th.name}": scale, f"leak.{th.name}": 0.0}
        sub = tuple(n for n in names if n not in hold)
        base_fixed = dict(kw["fixed"])
        refit = fit_segments(pose_t, pose, vehicle, cmd_t, duty, names=sub,
                             length_s=fit.plan.length_s, find_stretches=False,
                             **{**kw, "fixed": {**base_fixed, **hold},
                                "exclude": [(a, b) for a, b, _ in fit.plan.excluded]})
        d_cost = float(np.sum((refit.residuals / _sig(kw)) ** 2) -
                       np.sum((fit.residuals / _sig(kw)) ** 2))
        key = f"eff.{th.name}" if th.verdict != "stuck-open" else f"leak.{th.name}"
        over = fit.sigma[key]["clustered"] ** 2 / max(fit.sigma[key]["noise"] ** 2, 1e-300)
        th.lr = d_cost / max(over, 1e-12)
        if not th.lr > LR_LIMIT:
            th.why = (f"would be {th.verdict} ({th.why}) but the likelihood-ratio test across "
                      f"segments does not confirm it (statistic {th.lr:.1f} < {LR_LIMIT:g})")
            th.verdict = "ok"


def _sig(kw) -> np.ndarray:
    return np.array([kw["sigma_pos_m"], kw["sigma_pos_m"], kw["sigma_yaw_rad"]])
