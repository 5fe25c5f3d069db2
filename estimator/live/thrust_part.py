"""The thrust table's side of the live estimate: thrusts of duty rows and the thrust part
of the sigma.

:meth:`ThrustPart._thrust_of` maps duty rows to thrusts (the table's, or a structure's
virtual thrusts). The reported sigmas of m and Izz are the filter's (measurement noise)
and the thrust table's part, root-sum-square (:meth:`ThrustPart._sigmas`); the thrust part
is carried as fractions of m and Izz from the latest consider covariance
(:func:`estimator.batch.consider.batch_consider`: the LS window's fit, the end of the run,
:meth:`ThrustPart.final_thrust_part`), the table's common ``scale_rel`` before one exists.

:class:`ThrustPart` is a part of :class:`estimator.live.core.LiveEstimator` (a mixin): it
reads the estimator's table or structure, filter state, pose history and aligner.
"""

from __future__ import annotations

import math

import numpy as np

from estimator.live.structure_filter import com_block, com_index


class ThrustPart:
    """Thrusts and the thrust part of the sigma in :class:`~estimator.live.core.LiveEstimator`."""

    def _init_thrust_part(self) -> None:
        """The thrust table's part of the sigma, as fractions of m and Izz.

        Until a consider covariance has been computed on this run's data it is the table's
        common ``scale_rel`` (exact for a common scale error: m and Izz move by the same
        fraction); the ls-ekf LS window and the end of the run (:meth:`finish`) replace it
        with the full consider covariance of the data so far, whose fractions are carried
        forward. A table without uncertainty gives 0 and ``thrust_note`` says so."""
        from estimator.batch.consider import NO_UNCERTAINTY

        t = self.table
        unc = getattr(t, "uncertainty", None)
        # a structure's modules may have different tables: no common fraction before a fit
        r = float(unc.scale_rel) if unc is not None and self.structure is None else 0.0
        self.thrust_rel = (r, r)
        self.thrust_com_cov = np.zeros((2, 2))
        """A structure's thrust part of the centre of mass's covariance, m^2 (absolute)."""
        if not self._states_uncertainty():
            self.thrust_note = NO_UNCERTAINTY
        elif r > 0:
            self.thrust_note = ("thrust part: the table's common scale_rel until a consider "
                                "covariance is computed on this run (LS window, end of run)")
        else:
            self.thrust_note = ("thrust part: none until a consider covariance is computed on "
                                "this run (LS window, end of run)")

    def _states_uncertainty(self) -> bool:
        src = self.structure if self.structure is not None else self.table
        return bool(getattr(src, "states_uncertainty", False))

    def _thrust_sensitivity(self, duty):
        """The table's thrust sensitivity of ``duty`` rows (a structure's: of its virtual
        thrusts), or None without uncertainty."""
        if not self._states_uncertainty():
            return None
        if self.structure is not None:
            return self.structure.virtual_sensitivity(duty, clamp=True)
        from common.thrust_uncertainty import thrust_sensitivity

        return thrust_sensitivity(self.table, duty, clamp=True)

    def _thrust_of(self, duty):
        """(N, 4) thrusts of duty rows: the table's, or a structure's virtual thrusts."""
        if self.structure is not None:
            return self.structure.virtual_thrust(duty, clamp=True)
        return self.table.thrust_n(duty, clamp=True)

    def _input_rows(self, cmd_t, duty):
        """``(times, thrusts, sensitivity or None)`` of the batch fits' input: the commands'
        own rows, or a vehicle's through its valve dead time and rise
        (:meth:`common.vehicle.Vehicle.input_profile`)."""
        if self.structure is not None and getattr(self, "_timed", False):
            t, thrust = self.structure.input_profile(cmd_t, duty, clamp=True)
            sens = (self.structure.input_sensitivity(cmd_t, duty, clamp=True)[1]
                    if self._states_uncertainty() else None)
            return t, thrust, sens
        return cmd_t, self._thrust_of(duty), self._thrust_sensitivity(duty)

    def _set_thrust_rel(self, res, where: str) -> None:
        """Carry a batch fit's thrust part forward as fractions of its m and Izz."""
        st = res.sigma_thrust
        im, ii = 6 + res.names.index("mass"), 6 + res.names.index("izz")
        rel = (float(st[im] / res.z0[im]), float(st[ii] / res.z0[ii]))
        if all(math.isfinite(v) and v >= 0 for v in rel):
            self.thrust_rel = rel
            if self.structure is not None and res.cov_thrust is not None:
                self.thrust_com_cov = com_block(res.cov_thrust, com_index(res.names))
            self.thrust_note = (f"{res.thrust_note}; the thrust part from the consider covariance "
                                f"of {where}, as fractions of m and Izz")

    def final_thrust_part(self) -> None:
        """The consider covariance of the whole run at its end: batch LS from the filter's
        estimate on every pose and command seen, then the table's consider term."""
        if self.z is None or not self._states_uncertainty() or len(self.hist_t) < 10:
            return
        from estimator.batch.consider import batch_consider
        from estimator.batch.least_squares import batch_ls

        cmd_t, _, sens = self._input_rows(*self.aligner.commands())
        start = {"mass": float(self.z[6]), "izz": float(self.z[7])}
        if self.structure is not None:
            cx, cy, _ = self.com_m()
            start.update({k: v for k, v in (("cx", cx), ("cy", cy)) if k in self._names})
        kw = self._ls_kwargs(start)
        try:
            res = batch_ls(np.asarray(self.hist_t), np.asarray(self.hist_pose), cmd_t,
                           sens.thrust_n, **kw)
            if not res.converged:
                return
            c = batch_consider(res, cmd_t, sens, sigma_pos_m=kw["sigma_pos_m"],
                               sigma_yaw_rad=kw["sigma_yaw_rad"])
        except Exception:  # the end of a run never fails on this; the last fractions stay
            return
        if np.all(np.isfinite(c.cov_thrust)):
            res.add_thrust_covariance(c.cov_thrust, c.names)
            res.thrust_note = "sigma = measurement noise + thrust table uncertainty"
            self._set_thrust_rel(res, "the whole run")

    def _sigmas(self, m: float, sm: float, izz: float, si: float) -> tuple[float, ...]:
        """(mass total, izz total, mass noise, mass thrust, izz noise, izz thrust) sigmas."""
        tm, ti = abs(m) * self.thrust_rel[0], abs(izz) * self.thrust_rel[1]
        return math.hypot(sm, tm), math.hypot(si, ti), sm, tm, si, ti
