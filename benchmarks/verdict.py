"""The noisy-host rule: when a row that missed its target says "noisy host" instead of NO.

A row is *timed* (``"timed": True``) when its ``ok`` depends on wall-clock time (a rate,
a latency, an overhead). Its ``host`` field holds what the host did while it ran
(:mod:`benchmarks.host`; rows without a window of their own get their case's). The host
was *noisy* during the row when any of these held (thresholds in :data:`RULE`):

- the hypervisor stole >= 0.5 % of all CPUs' time (``steal_pct``),
- other processes used >= 10 % of all CPUs' time (``others_cpu_pct``),
- disk I/O waits took >= 5 % of all CPUs' time (``iowait_pct``),
- the probe (a fixed workload timed right before and right after the row) moved by
  >= 20 % (``probe_change_pct``);
- *slow host*, for a row that states its limit as numbers (``limit``, and ``better``:
  ``"higher"`` or ``"lower"``): the probe ran >= 10 % slower during the row (the faster of
  its two probes) than the fastest probe of the same ``make bench`` run
  (``slow_probe_pct``), and the row's value scaled to that fastest speed meets the limit.
  This machine's speed moves by 10-60 % from hour to hour without any steal showing in
  ``/proc``: the EKF row missed its 2e4 updates/s with 1.87e4 while its probes ran 15-20 %
  slower than the run's fastest, and made 2.07-2.15e4 alone a few minutes later. The
  scaling assumes a CPU-bound row (the probe's mix of small numpy products in a Python loop
  is the filters' own); a real regression larger than the slowdown still says NO.

Verdicts: ``yes`` (ok); ``-`` (not judged, ok None); ``noisy host`` (a timed row missed
its target on a noisy host and its untimed part, ``ok_untimed``, if any, held); ``NO``
otherwise: an untimed row that failed, a timed row that failed its untimed part, or a timed
row that failed on a quiet host. ``make bench`` exits non-zero on NO, not on noisy host.
Figures that could not be measured (None) count as quiet.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

YES, NO, NOISY, NOT_JUDGED = "yes", "NO", "noisy host", "-"


@dataclass(frozen=True)
class Rule:
    """Thresholds of the noisy-host rule, each in % (see the module docstring)."""

    steal_pct: float = 0.5
    others_cpu_pct: float = 10.0
    iowait_pct: float = 5.0
    probe_change_pct: float = 20.0
    slow_probe_pct: float = 10.0

    def describe(self) -> str:
        return (f"noisy host = during the row, steal >= {self.steal_pct:g} % or other processes' "
                f"CPU >= {self.others_cpu_pct:g} % or iowait >= {self.iowait_pct:g} % of all "
                f"CPUs' time, or the probe before/after the row moved >= "
                f"{self.probe_change_pct:g} %, or (rows with a numeric limit) the probe ran >= "
                f"{self.slow_probe_pct:g} % slower than the run's fastest and the value scaled "
                f"to that speed meets the limit")

    def to_dict(self) -> dict:
        return {**asdict(self), "text": self.describe()}


RULE = Rule()

_LABELS = {"steal_pct": "steal", "others_cpu_pct": "other processes' CPU",
           "iowait_pct": "iowait", "probe_change_pct": "probe moved"}


def noisy_reasons(host: dict | None, rule: Rule = RULE) -> list[str]:
    """Why the host was noisy during a window (empty: quiet), e.g. ``["steal 1.2 % >= 0.5 %"]``."""
    if not host:
        return []
    out = []
    for key, label in _LABELS.items():
        v, limit = host.get(key), getattr(rule, key)
        if v is not None and v >= limit:
            out.append(f"{label} {v:.3g} % >= {limit:g} %")
    return out


def fastest_probe_ms(hosts: list[dict | None]) -> float | None:
    """The fastest probe (ms) among these host windows' before/after probes; None if none."""
    ps = [h[k] for h in hosts if h for k in ("probe_before_ms", "probe_after_ms")
          if h.get(k) is not None and h[k] > 0]
    return min(ps) if ps else None


def slow_reasons(row: dict, fastest_ms: float | None, rule: Rule = RULE) -> list[str]:
    """Why a row that missed its numeric limit missed it on a slow host (see the module
    docstring), e.g. ``["probe 15 % slower than the run's fastest: 2.14e+04 at that speed,
    limit 2e+04 (higher is better)"]``; empty when the rule does not excuse it."""
    h, limit, better, value = row.get("host") or {}, row.get("limit"), row.get("better"), row.get("value")
    probes = [h.get(k) for k in ("probe_before_ms", "probe_after_ms") if h.get(k)]
    if not fastest_ms or not probes or limit is None or better not in ("higher", "lower") \
            or value is None:
        return []
    factor = min(probes) / fastest_ms  # > 1: the host ran slower during the row
    slower_pct = 100.0 * (factor - 1.0)
    if slower_pct < rule.slow_probe_pct:
        return []
    scaled = value * factor if better == "higher" else value / factor
    if (scaled >= limit) if better == "higher" else (scaled <= limit):
        return [f"probe {slower_pct:.0f} % slower than the run's fastest: {scaled:.3g} at that "
                f"speed, limit {limit:.3g} ({better} is better)"]
    return []


def verdict(row: dict, rule: Rule = RULE) -> str:
    """yes / NO / noisy host / - for one row (see the module docstring). The reasons are
    ``row["noisy"]`` when :func:`judge` put them there, else the host window's."""
    ok = row.get("ok")
    if ok is None:
        return NOT_JUDGED
    if ok:
        return YES
    if not row.get("timed") or row.get("ok_untimed") is False:
        return NO
    reasons = row["noisy"] if "noisy" in row else noisy_reasons(row.get("host"), rule)
    return NOISY if reasons else NO


def judge(rows: list[dict], case_hosts: dict[str, dict] | None = None,
          rule: Rule = RULE) -> list[dict]:
    """Each row with ``verdict`` and ``noisy`` (the reasons, for timed rows; a missed row's
    slow-host reason judged against the fastest probe of all rows and cases) added, and
    ``host`` taken from its case's window (``row["module"]`` names the case) when the row
    has none of its own; returns new dicts."""
    out = []
    fastest = fastest_probe_ms([r.get("host") for r in rows] + list((case_hosts or {}).values()))
    for r in rows:
        r = dict(r)
        if "host" not in r and case_hosts and r.get("module") in case_hosts:
            r["host"] = {**case_hosts[r["module"]], "window": "case"}
        if r.get("timed"):
            r["noisy"] = noisy_reasons(r.get("host"), rule)
            if not r.get("ok") and r.get("ok") is not None:
                r["noisy"] += slow_reasons(r, fastest, rule)
        r["verdict"] = verdict(r, rule)
        out.append(r)
    return out


def explain(row: dict) -> str:
    """Why a row got its verdict, one phrase (for the printed report)."""
    v = row.get("verdict") or verdict(row)
    if v in (YES, NOT_JUDGED):
        return ""
    if not row.get("timed"):
        return "not a timing row"
    if row.get("ok_untimed") is False:
        return "its untimed part failed"
    return "; ".join(row.get("noisy") or noisy_reasons(row.get("host"))) or "host quiet"


def exit_status(rows: list[dict], failed_cases: list[str]) -> int:
    """1 if a case crashed or a judged row is NO (a miss on a quiet host), else 0."""
    return 1 if failed_cases or any(r.get("verdict") == NO for r in rows) else 0


def summary(rows: list[dict]) -> dict[str, int]:
    return {v: sum(r.get("verdict") == v for r in rows) for v in (YES, NO, NOISY, NOT_JUDGED)}
