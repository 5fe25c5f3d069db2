"""The text output of ``tpods calibrate bifilar|trifilar``: the value, how it was found,
whether the model describes the trace, and the budget."""

from __future__ import annotations

import sys


def print_result(res, source: str) -> None:
    """Print an :class:`calibration.swing.bifilar_eq19.IzzResult` of any of the pendulum methods."""
    rel = res.izz_sigma_kgm2 / res.izz_kgm2
    print(f"Izz = {res.izz_kgm2:.6g} +- {res.izz_sigma_kgm2:.2g} kg m^2 ({100 * rel:.2g} %, k=1)"
          f"  [{res.method}: {source}]")
    d = res.details
    if res.method in ("eq19-times", "trifilar-times"):
        print(f"  period T = {d['period_s']:.5g} +- {d['u_period_s']:.2g} s "
              f"(trial std {d['period_std_s']:.2g} s)")
        if d["worst_trial_dev"] > 0.05:
            print(f"  warning: a timing differs by {100 * d['worst_trial_dev']:.0f} % from the "
                  "median: a miscounted oscillation?", file=sys.stderr)
    elif "signal" not in d:  # the bifilar yaw fit of calibration.swing.bifilar_fit
        print(f"  small-angle period {d['period0_s']:.5g} s; swing {d['amplitude_start_deg']:.1f} -> "
              f"{d['amplitude_end_deg']:.1f} deg over {d['n_oscillations']:g} oscillations; "
              f"residual rms {d['residual_rms_deg']:.2g} deg")
        print(f"  Eq. 19 on the trace's period {d['trace_period_s']:.5g} s: "
              f"{d['izz_small_angle_kgm2']:.6g} kg m^2 (amplitude correction "
              f"{100 * d['amplitude_correction']:+.2f} %)")
        print(f"  damping: viscous K1 = {d['k1_nms']:.3g} N m s, quadratic K2 = {d['k2_nms2']:.3g} N m s^2")
    else:
        _print_swing(res)
    var = res.izz_sigma_kgm2**2 or 1.0
    print("  contributions to u(Izz):")
    for k, v in sorted(res.contributions_kgm2.items(), key=lambda kv: -kv[1]):
        if v > 0:
            print(f"    {k:9s} {v:.2g} kg m^2 ({100 * v * v / var:.0f} % of the variance)")


def _print_swing(res) -> None:
    d = res.details
    unit = d["unit"]
    formula = "Eq. 19" if res.inputs.get("suspension") == "bifilar" else "the trifilar formula"
    print(f"  period method: {formula} on the damped-sine period {d['trace_period_s']:.6g} s: "
          f"{d['izz_period_kgm2']:.6g} kg m^2")
    if "izz_fit_kgm2" in d:
        print(f"  large-angle fit: {d['izz_fit_kgm2']:.6g} kg m^2; small-angle period "
              f"{d['period0_s']:.6g} s; swing {d['amplitude_start_deg']:.1f} -> "
              f"{d['amplitude_end_deg']:.1f} deg over {d['n_oscillations']:g} oscillations "
              f"(amplitude correction {100 * d['amplitude_correction']:+.2f} %)")
        held = d["damping_at_bound"]
        print(f"  damping: viscous K1 = {d['k1_nms']:.3g} N m s, quadratic K2 = {d['k2_nms2']:.3g} "
              "N m s^2" + (f" ({', '.join(held)} held at 0 by its bound)" if held else ""))
    if "amplitude_assumed_deg" in d:
        lo, hi = d["amplitude_assumed_deg"]
        print(f"  amplitude correction not applied (no --trace-scale): up to "
              f"{100 * d['amplitude_correction_bound']:+.2g} % for a swing of {lo:g}-{hi:g} deg, "
              "in the sigma as 'amplitude'")
    if d["signal"] == "rate":
        print(f"  gyro bias {d['offset']:.4g} rad/s, drift {d['drift_per_s']:.3g} rad/s^2")
    if "second_mode" in d:
        m = d["second_mode"]
        print(f"  second mode modelled: {m['name']} (residual/noise {m['residual_to_noise_without']:.2g} "
              "without it)")
    if "sensor_curvature" in d:
        print("  sensor curvature modelled (reading = u + k2 u^2 + k3 u^3 of the swing u)")
    verdict = ("the model describes the trace" if d["model_describes_trace"]
               else "the model does NOT describe the trace")
    print(f"  residual rms {d['residual_rms']:.3g} {unit} = {d['residual_to_noise']:.2g} x the "
          f"sensor noise {d['noise_sigma']:.2g} {unit} (limit {d['noise_limit']:g}): {verdict}")
    if "refit_reason" in d:
        print(f"  refitted with bounded damping, drift and second mode: {d['refit_reason']}")
