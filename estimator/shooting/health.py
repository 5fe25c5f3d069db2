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
- ``stuck-open``: the fit carries a constant body-frame force and moment (``bias.*``) that no
  command explains; where it is significant (chi-square, 3 dof, p < 0.001) and one
  thruster's own wrench explains it (the rest within chi-square 2 dof, p > 0.01) at more
  than :data:`LEAK_ABOVE` of its force, that thruster pushes while commanded closed (eight
  separate leaks are not identifiable: while most valves are closed they add only one
  3-component wrench). A significant bias no thruster explains is a warning (a tether, a
  hose);
- ``ok`` otherwise. ``resolution`` is the smallest loss the weak rule can name on this run
  (the median over the thrusters of its threshold).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from common.vehicle import Vehicle
from estimator.shooting.fit import MIN_CLUSTERS, SegmentFit, fit_segments

DEAD_BELOW = 0.3
WEAK_MIN_LOSS = 0.03
LEAK_ABOVE = 0.2
LR_LIMIT = 9.0
BODY = ("mass", "izz", "cx", "cy", "ax", "ay", "ct", "cr", "delay")
BIAS = ("bias.fx", "bias.fy", "bias.mz")
BIAS_CHI2 = 16.27
"""chi-square (3 dof) of the bias above which it is significant (p = 0.001)."""
EXPLAINED_CHI2 = 9.21
"""chi-square (2 dof) of what one thruster's wrench leaves of the bias, below which it
explains it (p = 0.01)."""


@dataclass
class ThrusterHealth:
    name: str
    efficiency: float
    sigma: float
    leak: float
    leak_sigma: float | None
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
        out = [f"thruster health ({what}; {self.fit.plan.n} segments; a loss of "
               f"{self.resolution * 100:.1f} % or more is named as weak):"]
        for t in self.thrusters:
            leak = (f", leak {t.leak:.2f} +- {t.leak_sigma:.2f}" if t.verdict == "stuck-open"
                    else "")
            out.append(f"  {t.name:<6} efficiency {t.efficiency:6.3f} +- {t.sigma:.3f}{leak}: "
                       f"{t.verdict}" + (f" ({t.why})" if t.why else ""))
        return out


def _health_names(vehicle: Vehicle, opens: np.ndarray, closes: np.ndarray, fixed) -> tuple:
    body = tuple(n for n in BODY if n != "mass" and n not in fixed)
    eff = tuple(f"eff.{t.name}" for i, t in enumerate(vehicle.thrusters) if opens[i])
    return body + eff + BIAS


def thruster_health(pose_t, pose, vehicle: Vehicle, cmd_t, duty_pct, *,
                    mass_kg: float | None = None, initial: Mapping[str, float] | None = None,
                    fixed: Mapping[str, float] | None = None, sigma_pos_m: float = 0.01,
                    sigma_yaw_rad: float = math.radians(1.0), length_s: float | None = None,
                    exclude: Sequence[tuple[float, float]] = (), clamp: bool = False
                    ) -> HealthReport:
    """Efficiencies, leaks and verdicts of every thruster of a run (module doc)."""
    duty = np.asarray(duty_pct, float)
    opens = np.any(duty > 0, axis=0) & np.array([not t.dead for t in vehicle.thrusters])
    closes = np.any(duty <= 0, axis=0)
    from estimator.shooting.fit import start_values
    from estimator.shooting.inputs import vehicle_channels

    ch = vehicle_channels(vehicle, cmd_t, duty, clamp=clamp)
    initial = start_values(vehicle, pose_t, pose, ch, dict(initial or {}), dict(fixed or {}))
    ref = float(mass_kg if mass_kg is not None else initial["mass"])
    fixed = {**dict(fixed or {}), "mass": ref}
    names = _health_names(vehicle, opens, closes, fixed)
    kw = dict(fixed=fixed, initial={k: v for k, v in initial.items() if k != "mass"},
              sigma_pos_m=sigma_pos_m, sigma_yaw_rad=sigma_yaw_rad, exclude=exclude, clamp=clamp)
    # at least MIN_CLUSTERS segments: the verdicts' sigma is the clustered one
    fit = fit_segments(pose_t, pose, vehicle, cmd_t, duty, names=names, length_s=length_s,
                       min_segments=MIN_CLUSTERS, **kw)
    eff = {t.name: fit.values.get(f"eff.{t.name}", math.nan) for t in vehicle.thrusters}
    known = np.array([v for v in eff.values() if math.isfinite(v)])
    scale = float(np.median(known)) if mass_kg is None and len(known) else 1.0
    out, thresholds = [], []
    for t in vehicle.thrusters:
        e = eff[t.name] / scale
        s = fit.sigma.get(f"eff.{t.name}", {}).get("total", math.nan) / abs(scale)
        lk, ls = 0.0, None  # a leak is estimated only for a stuck-open verdict (_stuck_open)
        others = np.array([eff[o.name] / scale for o in vehicle.thrusters
                           if o.name != t.name and math.isfinite(eff[o.name])])
        spread = 1.4826 * float(np.median(np.abs(others - np.median(others)))) if len(others) > 2 else 0.0
        verdict, why = _verdict(e, s, lk, ls, spread, opens[vehicle.thrusters.index(t)])
        out.append(ThrusterHealth(t.name, e, s, lk, ls, verdict, None, why))
        thresholds.append(max(WEAK_MIN_LOSS, 2 * spread, 3 * s) if math.isfinite(s) else math.nan)
    _stuck_open(out, fit, vehicle, scale)
    _confirm(out, fit, pose_t, pose, vehicle, cmd_t, duty, names, scale, length_s, kw)
    # the smallest loss a verdict of weak can be given for on this run: the weak rule's own
    # threshold (3 %, twice the peers' spread, 3 sigma), the median over the thrusters
    known = [x for x in thresholds if math.isfinite(x)]
    resolution = float(np.median(known)) if known else math.nan
    return HealthReport(out, mass_kg is None, ref, fit, resolution)


def _stuck_open(report: list, fit: SegmentFit, vehicle: Vehicle, scale: float) -> None:
    """The stuck-open test on the fitted bias (module doc): the verdict of the thruster
    whose wrench explains it, or a warning on the fit when none does."""
    idx = [fit.names.index(b) for b in BIAS if b in fit.names]
    if len(idx) != 3:
        return
    b = np.array([fit.values[n] for n in BIAS])
    cov = fit.cov["total"][np.ix_(idx, idx)]
    try:
        info = np.linalg.inv(cov)
    except np.linalg.LinAlgError:
        return
    chi_b = float(b @ info @ b)
    if not chi_b > BIAS_CHI2:
        return
    best = None
    for th, t in zip(report, vehicle.thrusters, strict=True):
        force = t.force_n if t.force_n is not None else 0.0
        c = force * scale * np.asarray(t.wrench_column())
        cc = float(c @ info @ c)
        if cc <= 0:
            continue
        lam = float(c @ info @ b) / cc
        rest = b - lam * c
        chi = float(rest @ info @ rest)
        if best is None or chi < best[0]:
            best = (chi, lam, 1.0 / math.sqrt(cc), th)
    if best is not None and best[0] < EXPLAINED_CHI2 and best[1] > LEAK_ABOVE:
        chi, lam, sig, th = best
        th.leak, th.leak_sigma = lam, sig
        th.verdict = "stuck-open"
        th.why = (f"pushes with {lam * 100:.0f} % of its force while commanded closed (a "
                  f"constant wrench, chi-square {chi_b:.0f}, that its own explains)")
        return
    fit.warnings.append(
        f"a constant body-frame force and moment no command explains: fx {b[0]:+.3g} N, fy "
        f"{b[1]:+.3g} N, mz {b[2]:+.3g} N m (chi-square {chi_b:.0f}, 3 dof); no single "
        "thruster's wrench explains it: a tether, a hose or a leak shared by several valves")


def _verdict(e, s, leak, leak_s, spread, opened) -> tuple[str, str]:
    if not opened:
        return "ok", "never commanded open in this run: not tested"
    if e < -DEAD_BELOW and e + 3 * s < 0:
        return "reversed", "its thrust pushes the other way"
    if e < DEAD_BELOW and e + 3 * s < 1.0:
        return "dead", f"gives {max(e, 0) * 100:.0f} % of its stated thrust"
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
        hold = ({b: 0.0 for b in BIAS} if th.verdict == "stuck-open"
                else {f"eff.{th.name}": scale})
        sub = tuple(n for n in names if n not in hold)
        base_fixed = dict(kw["fixed"])
        refit = fit_segments(pose_t, pose, vehicle, cmd_t, duty, names=sub,
                             length_s=fit.plan.length_s, find_stretches=False,
                             **{**kw, "fixed": {**base_fixed, **hold},
                                "exclude": [(a, b) for a, b, _ in fit.plan.excluded]})
        d_cost = float(np.sum((refit.residuals / _sig(kw)) ** 2) -
                       np.sum((fit.residuals / _sig(kw)) ** 2))
        keys = list(BIAS) if th.verdict == "stuck-open" else [f"eff.{th.name}"]
        over = float(np.mean([fit.sigma[k]["clustered"] ** 2 / max(fit.sigma[k]["noise"] ** 2,
                                                                    1e-300) for k in keys]))
        th.lr = d_cost / max(over, 1e-12)
        limit = BIAS_CHI2 if th.verdict == "stuck-open" else LR_LIMIT  # 3 dof or 1
        if not th.lr > limit:
            th.why = (f"would be {th.verdict} ({th.why}) but the likelihood-ratio test across "
                      f"segments does not confirm it (statistic {th.lr:.1f} < {limit:g})")
            th.verdict = "ok"


def _sig(kw) -> np.ndarray:
    return np.array([kw["sigma_pos_m"], kw["sigma_pos_m"], kw["sigma_yaw_rad"]])
