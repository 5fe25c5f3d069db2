"""The text report of a pendulum's Izz (:mod:`calibration.swing.measure`): the value, how it
was found, whether the model describes the trace, and the budget, as lines (kg m^2, s, deg)."""

from __future__ import annotations


def summary_lines(res, source: str) -> tuple[list[str], list[str]]:
    """The report of an :class:`calibration.swing.bifilar_eq19.IzzResult` of any of the
    pendulum methods (``source``: what was fitted): its lines, and the notes that go to
    stderr (a timing far from the others)."""
    out: list[str] = []
    notes: list[str] = []
    rel = res.izz_sigma_kgm2 / res.izz_kgm2
    out.append(f"Izz = {res.izz_kgm2:.6g} +- {res.izz_sigma_kgm2:.2g} kg m^2 ({100 * rel:.2g} %, k=1)"
               f"  [{res.method}: {source}]")
    d = res.details
    if res.method in ("eq19-times", "trifilar-times"):
        out.append(f"  period T = {d['period_s']:.5g} +- {d['u_period_s']:.2g} s "
                   f"(trial std {d['period_std_s']:.2g} s)")
        if d["worst_trial_dev"] > 0.05:
            notes.append(f"  warning: a timing differs by {100 * d['worst_trial_dev']:.0f} % from the "
                         "median: a miscounted oscillation?")
    elif "signal" not in d:  # the bifilar yaw fit of calibration.swing.bifilar_fit
        out.append(f"  small-angle period {d['period0_s']:.5g} s; swing {d['amplitude_start_deg']:.1f} -> "
                   f"{d['amplitude_end_deg']:.1f} deg over {d['n_oscillations']:g} oscillations; "
                   f"residual rms {d['residual_rms_deg']:.2g} deg")
        out.append(f"  Eq. 19 on the trace's period {d['trace_period_s']:.5g} s: "
                   f"{d['izz_small_angle_kgm2']:.6g} kg m^2 (amplitude correction "
                   f"{100 * d['amplitude_correction']:+.2f} %)")
        out.append(f"  damping: viscous K1 = {d['k1_nms']:.3g} N m s, quadratic K2 = {d['k2_nms2']:.3g} N m s^2")
    else:
        out += _swing_lines(res)
    var = res.izz_sigma_kgm2**2 or 1.0
    out.append("  contributions to u(Izz):")
    for k, v in sorted(res.contributions_kgm2.items(), key=lambda kv: -kv[1]):
        if v > 0:
            out.append(f"    {k:9s} {v:.2g} kg m^2 ({100 * v * v / var:.0f} % of the variance)")
    return out, notes


def _swing_lines(res) -> list[str]:
    out: list[str] = []
    d = res.details
    unit = d["unit"]
    formula = "Eq. 19" if res.inputs.get("suspension") == "bifilar" else "the trifilar formula"
    out.append(f"  period method: {formula} on the damped-sine period {d['trace_period_s']:.6g} s: "
               f"{d['izz_period_kgm2']:.6g} kg m^2")
    if "izz_fit_kgm2" in d:
        out.append(f"  large-angle fit: {d['izz_fit_kgm2']:.6g} kg m^2; small-angle period "
                   f"{d['period0_s']:.6g} s; swing {d['amplitude_start_deg']:.1f} -> "
                   f"{d['amplitude_end_deg']:.1f} deg over {d['n_oscillations']:g} oscillations "
                   f"(amplitude correction {100 * d['amplitude_correction']:+.2f} %)")
        held = d["damping_at_bound"]
        out.append(f"  damping: viscous K1 = {d['k1_nms']:.3g} N m s, quadratic K2 = {d['k2_nms2']:.3g} "
                   "N m s^2" + (f" ({', '.join(held)} held at 0 by its bound)" if held else ""))
    if "amplitude_assumed_deg" in d:
        lo, hi = d["amplitude_assumed_deg"]
        out.append(f"  amplitude correction not applied (no --trace-scale): up to "
                   f"{100 * d['amplitude_correction_bound']:+.2g} % for a swing of {lo:g}-{hi:g} deg, "
                   "in the sigma as 'amplitude'")
    if d["signal"] == "rate":
        out.append(f"  gyro bias {d['offset']:.4g} rad/s, drift {d['drift_per_s']:.3g} rad/s^2")
    if "second_mode" in d:
        m = d["second_mode"]
        out.append(f"  second mode modelled: {m['name']} (residual/noise {m['residual_to_noise_without']:.2g} "
                   "without it)")
    if "sensor_curvature" in d:
        out.append("  sensor curvature modelled (reading = u + k2 u^2 + k3 u^3 of the swing u)")
    verdict = ("the model describes the trace" if d["model_describes_trace"]
               else "the model does NOT describe the trace")
    out.append(f"  residual rms {d['residual_rms']:.3g} {unit} = {d['residual_to_noise']:.2g} x the "
               f"sensor noise {d['noise_sigma']:.2g} {unit} (limit {d['noise_limit']:g}): {verdict}")
    if "refit_reason" in d:
        out.append(f"  refitted with bounded damping, drift and second mode: {d['refit_reason']}")
    return out
