"""The live filter of a structure or a vehicle: mass, Izz, the centre
of mass; its report.

On a structure the live estimator runs the extended filter's model: mass, Izz about the
centre of mass and the centre of mass (cx, cy) in the tracked frame (a cx or cy that the
structure's [body] gives as known is fixed), the offset-aware pose update
(:func:`estimator.filters.kernels._update_offset`) in the direct parameter form, the
process noise added after every RK4 step. :meth:`StructureFilter.com_m` and the estimate
message's centre-of-mass keys (:meth:`StructureFilter._com_keys`) report it.

:class:`StructureFilter` is a part of :class:`estimator.live.core.LiveEstimator` (a mixin):
it reads the estimator's structure, settings, filter state, hold segments and thrust part.
A vehicle (:class:`common.vehicle.Vehicle`) takes the same filter: its N duties come on one
command stream, its valve dead time and rise shape the hold segments
(:mod:`estimator.live.valve_segments`), and when its [body] gives neither mass nor Izz the
LS window's fit starts from a mass scan (:mod:`estimator.live.scan_job`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from common.errors import UserError
from estimator.filters.kernels import _offset_spec, _predict, _update_offset, filter_plant
from estimator.live.valve_segments import has_timing, timed_segments

STRUCTURE_NAMES = ("mass", "izz", "cx", "cy")
"""The live estimator's unknowns on a structure: mass, Izz about the centre of
mass and the centre of mass in the tracked frame (cx or cy given as known in the
structure's [body] are fixed instead)."""


def com_index(names: Sequence[str]) -> list[int | None]:
    """State indices of cx, cy in a state ``(x, y, psi, u, v, r, *names)`` (None: fixed)."""
    return [6 + names.index(n) if n in names else None for n in ("cx", "cy")]


def com_block(M: np.ndarray, idx: list[int | None]) -> np.ndarray:
    """The (2, 2) block of ``M`` on the rows and columns ``idx`` of cx, cy (0 for a fixed one)."""
    out = np.zeros((2, 2))
    for a, ia in enumerate(idx):
        for b, ib in enumerate(idx):
            if ia is not None and ib is not None:
                out[a, b] = M[ia, ib]
    return out


class StructureFilter:
    """A structure's filter in :class:`~estimator.live.core.LiveEstimator`."""

    def _init_structure_filter(self) -> None:
        """The extended filter of a structure: mass, izz, cx, cy estimated (a cx or cy the
        structure's [body] gives as known is fixed; a [body] value with a sigma is a prior
        of the LS window's fit, as in ``tpods estimate batch``), the known terms of the
        EkfConfig fixed; the process noise of its first 8 states (added after every RK4
        step, as :func:`estimator.filters.ext.run_ext_ekf` does), none on cx, cy; the
        direct parameter form (the 1/m form was overconfident with cx, cy estimated, see
        estimator.estimate._extended_filter)."""
        cfg = self.config.ekf
        body = self.structure.body
        known, priors = body.known(), body.priors()
        if "mass" in known or "izz" in known:
            which = " and ".join(n for n in ("mass", "izz") if n in known)
            raise UserError(f"{self.structure.source}: [body] gives {which} as known (no sigma), "
                            "but the live filter always estimates mass and Izz; give it a sigma "
                            "(a prior), or post-process with `tpods estimate batch --method ls`")
        self._names = tuple(n for n in STRUCTURE_NAMES if n not in known)
        self._fixed = cfg.known_params
        self._fixed.update({n: known[n] for n in ("cx", "cy") if n in known})
        self._priors = {n: priors[n] for n in self._names if n in priors}
        self._plant = filter_plant(self._names, self._fixed)
        self._q_nz = tuple((i, float(q)) for i, q in enumerate(cfg.q_psd) if q)
        self._off = _offset_spec(self._plant)
        guess = self.structure.initial_guess()
        self._guess = {k: guess[k] for k in self._names}
        self._timed = has_timing(self.structure)
        # a vehicle whose [body] gives neither mass nor Izz: the window fit starts from a
        # mass scan (the paper's module is no start for a 23 kg satellite)
        self._scan_reach_m = (self.structure.extent_m()
                              if self.structure.kind == "vehicle" and body.mass_kg is None
                              and body.izz_kgm2 is None and not self.structure.is_single_at_origin
                              else None)

    def _prior_vector(self):
        """The [body] priors as ``(zbar, Pbar)`` over ``(x, y, psi, u, v, r, *names)`` for
        batch LS (other entries diffuse), or None."""
        if not self._priors:
            return None
        n = 6 + len(self._names)
        zbar, P = np.zeros(n), np.diag(np.full(n, np.inf))
        for j, name in enumerate(self._names):
            if name in self._priors:
                zbar[6 + j], P[6 + j, 6 + j] = self._priors[name][0], self._priors[name][1] ** 2
        return zbar, P

    def _com_index(self) -> list[int | None]:
        """State indices of cx, cy (None: fixed)."""
        return com_index(self._names)

    def _step_structure(self, z, P, t_prev, t, meas, use):
        cfg = self.config.ekf
        if t_prev is not None and t > t_prev:
            if self._timed:  # a vehicle's valve dead time and rise
                a = self.aligner
                seg_dt, seg_w = timed_segments(self.structure, a._cmd_t, a._cmd_d, t_prev, t,
                                               cfg.arm_m)
            else:
                seg_dt, seg_w = self._segments(t_prev, t)
            with np.errstate(over="ignore", invalid="ignore"):
                z, P, _ = _predict(z, P, seg_dt, seg_w, self._plant, self._q_nz, cfg.max_step_s,
                                   True)
        nis = math.nan
        if use and np.all(np.isfinite(z)) and np.all(np.isfinite(P)):
            z, P, (nis, _) = _update_offset(z, P, meas, self._R, self._off)
        return z, P, nis

    def com_m(self) -> tuple[float, float, np.ndarray] | None:
        """A structure's centre of mass (cx, cy, m, tracked frame) and its (2, 2) noise
        covariance, m^2 (0 for a fixed one; None before the first estimate or for a module)."""
        if self.structure is None or self.z is None:
            return None
        idx = self._com_index()
        c = [float(self.z[i]) if i is not None else float(self._fixed[n])
             for i, n in zip(idx, ("cx", "cy"), strict=True)]
        return c[0], c[1], com_block(self.P, idx)

    def _com_keys(self) -> dict[str, Any]:
        """A structure's centre of mass (tracked frame, m): total sigmas (noise + thrust
        table), their parts, the (2, 2) total covariance ``cov_com_m2`` and Izz about the
        tracked origin (kg m^2; its sigma from the noise covariance of m, Izz, cx, cy and
        the thrust parts of m and Izz, first order)."""
        z, P = self.z, self.P
        cx, cy, cn = self.com_m()
        ct = self.thrust_com_cov
        cov = cn + ct
        m, izz = float(z[6]), float(z[7])
        g = np.zeros(len(z))
        g[6], g[7] = cx * cx + cy * cy, 1.0
        for i, v in zip(self._com_index(), (2 * m * cx, 2 * m * cy), strict=True):
            if i is not None:
                g[i] = v
        # the thrust part of m and Izz added linearly: exact for a common scale error (m and
        # Izz move together), conservative otherwise
        t_o = abs(g[6] * m * self.thrust_rel[0]) + abs(izz * self.thrust_rel[1])
        var_o = float(g @ P @ g) + t_o * t_o
        sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
        return {"structure": self.structure.name,
                "com_x_m": cx, "com_x_sigma_m": float(sd[0]),
                "com_y_m": cy, "com_y_sigma_m": float(sd[1]),
                "com_x_sigma_noise_m": math.sqrt(max(cn[0, 0], 0.0)),
                "com_y_sigma_noise_m": math.sqrt(max(cn[1, 1], 0.0)),
                "com_x_sigma_thrust_m": math.sqrt(max(ct[0, 0], 0.0)),
                "com_y_sigma_thrust_m": math.sqrt(max(ct[1, 1], 0.0)),
                "cov_com_m2": cov.tolist(),
                "izz_origin_kgm2": izz + m * (cx * cx + cy * cy),
                "izz_origin_sigma_kgm2": math.sqrt(max(var_o, 0.0))}
