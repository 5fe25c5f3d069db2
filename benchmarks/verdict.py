"""The noisy-host rule: when a row that missed its target says "noisy host" instead of NO.

A row is *timed* (``"timed": True``) when its ``ok`` depends on wall-clock time (a rate,
a latency, an overhead). Its ``host`` field holds what the host did while it ran
(:mod:`benchmarks.host`; rows without a window of their own get their case's). The host
was *noisy* during the row when any of these held (thresholds in :data:`RULE`):

- the hypervisor stole >= 0.5 % of all CPUs' time (``steal_pct``),
- other processes used >= 10 % of all CPUs' time (``others_cpu_pct``),
- disk I/O waits took >= 5 % of all CPUs' time (``iowait_pct``),
- the probe (a fixed workload timed right before and right after the row) moved by
  >= 20 % (``probe_change_pct``).

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

    def describe(self) -> str:
        return (f"noisy host = during the row, steal >= {self.steal_pct:g} % or other processes' "
                f"CPU >= {self.others_cpu_pct:g} % or iowait >= {self.iowait_pct:g} % of all "
                f"CPUs' time, or the probe before/after the row moved >= "
                f"{self.probe_change_pct:g} %")

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


def verdict(row: dict, rule: Rule = RULE) -> str:
    """yes / NO / noisy host / - for one row (see the module docstring)."""
    ok = row.get("ok")
    if ok is None:
        return NOT_JUDGED
    if ok:
        return YES
    if not row.get("timed") or row.get("ok_untimed") is False:
        return NO
    return NOISY if noisy_reasons(row.get("host"), rule) else NO


def judge(rows: list[dict], case_hosts: dict[str, dict] | None = None,
          rule: Rule = RULE) -> list[dict]:
    """Each row with ``verdict`` and ``noisy`` (the reasons, for timed rows) added, and
    ``host`` taken from its case's window (``row["module"]`` names the case) when the row
    has none of its own; returns new dicts."""
    out = []
    for r in rows:
        r = dict(r)
        if "host" not in r and case_hosts and r.get("module") in case_hosts:
            r["host"] = {**case_hosts[r["module"]], "window": "case"}
        if r.get("timed"):
            r["noisy"] = noisy_reasons(r.get("host"), rule)
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
