"""What the live estimator says about the clock offset at the end of a run: the offset
measured (and the one applied, and what is left), and warnings (one line each, for stderr).

An offset between the mocap host's clock and the player's shifts every pose against the
commands exactly as a valve dead time would, so it is warned about when measured and
clearly there, and when it could not be measured while a vehicle states its valve delay's
sigma (an offset above that sigma would then go unseen).
"""

from __future__ import annotations

from typing import Any

MEASURE_HINT = ("it is measured from the arrival delays of at least 2 s of both streams "
                "received live (tpods estimate live taking the mocap bridge's poses and "
                "tpods run play's commands), or give it: --clock-offset-ms MS")


def clock_offset_lines(summary: dict[str, Any], delay_sigma_s: float | None = None
                       ) -> tuple[list[str], list[str]]:
    """``(info, warnings)`` lines from a live summary; ``delay_sigma_s``: the valve delay's
    stated 1-sigma (s; None: none stated)."""
    info: list[str] = []
    warn: list[str] = []
    off, sig = summary.get("clock_offset_ms"), summary.get("clock_offset_sigma_ms")
    given = summary.get("clock_offset_given_ms") or 0.0
    info.extend(ping_lines(summary.get("clock_ping_player")))
    if off is None:
        if delay_sigma_s is not None and not given:
            c = summary.get("counters", {})
            warn.append(f"the mocap and player hosts' clock offset is unmeasured ({c.get('poses_rx', 0)} "
                        f"poses, {c.get('cmds_rx', 0)} commands received): an offset larger than "
                        f"the valve delay's stated sigma ({1e3 * delay_sigma_s:.3g} ms) would be "
                        f"taken for a dead time; {MEASURE_HINT}")
        return info, warn
    g = f", after the {given:+g} ms given" if given else ""
    info.append(f"live: clock offset, mocap host minus player host{g}: {off:+.2f} +/- {sig:.2f} ms "
                f"(from the lower envelopes of the pose and command delays, "
                f"{summary['clock_offset_windows']} windows of 1 s)")
    applied = summary.get("clock_offset_applied")
    if applied:
        res = applied.get("residual_ms")
        left = ("not yet measured" if res is None else
                f"{res:+.2f} +/- {applied['residual_sigma_ms']:.2f} ms "
                f"({applied['residual_windows']} windows)")
        info.append(f"live: applied {applied['offset_ms']:+.2f} ms from pose time "
                    f"{applied['from_pose_t_s']:.3f} s on ({applied['windows']} windows); "
                    f"offset left since: {left}")
    if abs(off) > max(1.0, 3.0 * sig):
        done = (f"{applied['offset_ms']:+.1f} ms was taken off the poses from "
                f"{applied['from_pose_t_s']:.3f} s on, the poses before carry it"
                if applied else "every pose is shifted against the commands as by a valve "
                "dead time of that size")
        warn.append(f"the mocap and player hosts' clocks differ by {off:+.1f} ms: {done}; "
                    "synchronise the hosts (NTP/PTP) before fitting a dead time")
    return info, warn


def ping_lines(ping: dict[str, Any] | None) -> list[str]:
    """The round-trip measurement of the player host's clock, one line (none if not asked)."""
    if not ping or not ping.get("asked"):
        return []
    if ping.get("offset_ms") is None:
        return [f"live: player host's clock by round trip: not measured ({ping['answered']} of "
                f"{ping['asked']} queries on {ping['key']} answered; tpods run play answers them)"]
    return [f"live: player host's clock minus this host's, by round trip: {ping['offset_ms']:+.2f} "
            f"+/- {ping['sigma_ms']:.2f} ms (shortest round trip {ping['rtt_min_ms']:.2f} ms, "
            f"{ping['kept']} of {ping['answered']} exchanges kept; where this host is the mocap "
            "host, the offset above is minus it)"]
