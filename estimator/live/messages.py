"""The live estimator's output: the estimate message, its publishing, stats and summary.

:meth:`EstimateMessages.estimate` builds the ``tpods.estimate/1`` message (a dict; a
structure's centre-of-mass keys added), :meth:`EstimateMessages._encode` the same payload
straight to bytes with :data:`common.wire.EST_FMT` (the fast path of a module), and
:meth:`EstimateMessages._publish` hands one to ``publish`` or ``publish_bytes``, counting
what fails. :meth:`EstimateMessages.stats` and :meth:`EstimateMessages.summary` are the
counters and the JSON-ready end of a run.

:class:`EstimateMessages` is a part of :class:`estimator.live.core.LiveEstimator` (a mixin):
it reads the estimator's filter state, settings, counters, health and thrust part.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from common.wire import EST_FMT as _EST_FMT
from common.wire import EST_SCHEMA, encode_estimate
from estimator.filters.config import STATE_NAMES


class EstimateMessages:
    """Estimate messages of :class:`~estimator.live.core.LiveEstimator`."""

    def estimate(self, now: float | None = None) -> dict[str, Any] | None:
        """The current estimate message (None before the first update)."""
        if self.z is None:
            return None
        z = self.z
        sig = np.sqrt(np.maximum(self.P.diagonal(), 0.0))
        sm, si, nm, tm, ni, ti = self._sigmas(float(z[6]), float(sig[6]), float(z[7]), float(sig[7]))
        out = {
            "schema": EST_SCHEMA, "body": self.body, "seq": self._seq,
            "t": self.t_last, "frame": self.frame_last,
            "t_pub": time.time() if now is None else now,
            "method": self.config.method, "phase": self.phase,
            "mass_kg": float(z[6]), "mass_sigma_kg": sm,
            "izz_kgm2": float(z[7]), "izz_sigma_kgm2": si,
            "mass_sigma_noise_kg": nm, "mass_sigma_thrust_kg": tm,
            "izz_sigma_noise_kgm2": ni, "izz_sigma_thrust_kgm2": ti,
            "state": dict(zip(STATE_NAMES[:6], z[:6].tolist(), strict=True)),
            "state_sigma": dict(zip(STATE_NAMES[:6], sig[:6].tolist(), strict=True)),
            "n_updates": self.counters.updates,
            "nis": None if math.isnan(self.last_nis) else float(self.last_nis),
            "diverged": self.diverged,
            "inconsistent": self.inconsistent,
            "rev": self.rev_last, "revised": self.rev_last > 0,
        }
        if self.structure is not None:
            out.update(self._com_keys())
        return out

    def _publish(self, now: float) -> None:
        self._last_pub = now
        if self.z is None or (self.publish is None and self.publish_bytes is None):
            return
        self._seq += 1
        try:
            if self.publish_bytes is not None:
                if self.structure is not None:  # the extra keys: the general encoder
                    msg = self.estimate()
                    msg["seq"] = self._seq
                    self.publish_bytes(encode_estimate(msg))
                else:
                    self.publish_bytes(self._encode())
            else:
                msg = self.estimate()
                msg["seq"] = self._seq
                self.publish(msg)
            self.counters.estimates_published += 1
            if self.rev_last:
                self.counters.revised_published += 1
        except Exception:
            self.counters.publish_errors += 1

    def _encode(self) -> bytes:
        """The current estimate as a ``tpods.estimate/1`` payload (same keys as :meth:`estimate`)."""
        z = self.z.tolist()
        d = self.P.diagonal().tolist()
        sg = [math.sqrt(v) if v > 0 else 0.0 for v in d]
        nis = "null" if math.isnan(self.last_nis) else repr(float(self.last_nis))
        sm, si, nm, tm, ni, ti = self._sigmas(z[6], sg[6], z[7], sg[7])
        return (_EST_FMT % (self._body_json, self._seq, self.t_last, self.frame_last, time.time(),
                            self.config.method, self.phase, z[6], sm, z[7], si, nm, tm, ni, ti,
                            *z[:6], *sg[:6], self.counters.updates, nis,
                            "true" if self.diverged else "false",
                            "true" if self.inconsistent else "false", self.rev_last,
                            "true" if self.rev_last else "false")).encode()

    def stats(self) -> dict[str, Any]:
        d = self.counters.as_dict()
        d.update({f"align_{k}": v for k, v in self.aligner.stats.as_dict().items()})
        d["pending"] = self.aligner.pending
        d["clock_overlap_skipped"] = self.clock_apply.skipped
        if self.merger is not None:
            d.update({f"merge_{k}": v for k, v in self.merger.stats.as_dict().items()})
        return d

    def summary(self) -> dict[str, Any]:
        """Final estimate, phase, LS details and counters (JSON-ready)."""
        est = self.estimate() or {}
        out = {k: est.get(k) for k in ("method", "phase", "mass_kg", "mass_sigma_kg", "izz_kgm2",
                                       "izz_sigma_kgm2", "mass_sigma_noise_kg",
                                       "mass_sigma_thrust_kg", "izz_sigma_noise_kgm2",
                                       "izz_sigma_thrust_kgm2", "state", "state_sigma",
                                       "n_updates", "diverged", "inconsistent")}
        out["thrust_uncertainty"] = {"included": self._states_uncertainty(),
                                     "note": self.thrust_note}
        if self.structure is not None:
            out["structure"] = self.structure.name
            if self.structure.kind == "vehicle":
                out["vehicle"] = self.structure.name
                out["thrusters"] = [t.name for t in self.structure.thrusters]
            else:
                out["modules"] = [m.name for m in self.structure.modules]
            out.update({k: est.get(k) for k in (
                "com_x_m", "com_x_sigma_m", "com_y_m", "com_y_sigma_m", "com_x_sigma_noise_m",
                "com_y_sigma_noise_m", "com_x_sigma_thrust_m", "com_y_sigma_thrust_m",
                "cov_com_m2", "izz_origin_kgm2", "izz_origin_sigma_kgm2")})
        out["t_last_lab"] = self.t_last
        out["restart_t_lab"] = self.restart_t
        if self.ls_result is not None:
            r = self.ls_result
            out["ls"] = {"mass_kg": r.mass_kg, "mass_sigma_kg": r.mass_sigma_kg,
                         "izz_kgm2": r.izz_kgm2, "izz_sigma_kgm2": r.izz_sigma_kgm2,
                         "window_s": self.config.ls_window_s, "elapsed_s": self.ls_elapsed_s}
        if self.ls_error:
            out["ls_error"] = self.ls_error
        out.update(self.gaps.summary())
        out["clock_offset_given_ms"] = 1e3 * self.config.clock_offset_s
        off = self.clock_meter.estimate()
        out.update(off.as_dict() if off is not None else
                   {"clock_offset_ms": None, "clock_offset_sigma_ms": None,
                    "clock_offset_windows": 0})
        out.update(self.clock_apply.as_dict())
        out["clock_ping_player"] = self.clock_ping
        out["counters"] = self.stats()
        return out


