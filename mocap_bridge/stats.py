"""Bridge statistics: counters per body, per-second rates, the stats payload and console line."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from typing import Any

from common.wire import STATS_SCHEMA


@dataclass
class BodyStats:
    """Counters of one rigid body."""

    published: int = 0
    occluded: int = 0
    duplicates: int = 0
    gaps: int = 0          # missing frame numbers between consecutive frames of this body
    restarts: int = 0      # frame counter jumped far back (mocap restarted); accepted
    last_frame: int | None = None
    last_t: float | None = None


@dataclass
class BridgeStats:
    """All counters of a bridge; :meth:`snapshot` turns them into a stats message."""

    source: str = ""
    started: float = field(default_factory=time.time)
    bodies: dict[str, BodyStats] = field(default_factory=dict)
    source_counters: dict[str, int] = field(default_factory=dict)
    _prev: dict[str, Any] = field(default_factory=dict)

    def totals(self) -> dict[str, int]:
        b = self.bodies.values()
        return {
            "published": sum(s.published for s in b),
            "occluded": sum(s.occluded for s in b),
            "duplicates": sum(s.duplicates for s in b),
            "gaps": sum(s.gaps for s in b),
        }

    def snapshot(self, now: float | None = None) -> dict[str, Any]:
        """Counters, and rates since the previous snapshot (per second)."""
        now = time.time() if now is None else now
        tot = self.totals()
        src = dict(self.source_counters)
        prev = self._prev
        dt = now - prev.get("t", self.started)

        def rate(cur: float, old: float) -> float:
            return (cur - old) / dt if dt > 0 else 0.0

        per_body = {}
        for name, s in list(self.bodies.items()):
            per_body[name] = {
                "published": s.published, "occluded": s.occluded, "duplicates": s.duplicates,
                "gaps": s.gaps, "restarts": s.restarts, "last_frame": s.last_frame,
                "rate_hz": rate(s.published, prev.get("body", {}).get(name, 0)),
            }
        snap = {
            "schema": STATS_SCHEMA, "t": now, "source": self.source,
            "uptime_s": now - self.started,
            **tot,
            "malformed": src.get("malformed", 0),
            "datagrams": src.get("datagrams", 0),
            "source_counters": src,
            "rate_hz": rate(tot["published"], prev.get("published", 0)),
            "datagram_rate_hz": rate(src.get("datagrams", 0), prev.get("datagrams", 0)),
            "bodies": per_body,
        }
        self._prev = {"t": now, "published": tot["published"], "datagrams": src.get("datagrams", 0),
                      "body": {k: v["published"] for k, v in per_body.items()}}
        return snap


def encode_stats(snap: dict[str, Any]) -> bytes:
    return json.dumps(snap, separators=(",", ":")).encode()


def console_line(snap: dict[str, Any]) -> str:
    """One line of live statistics for the terminal."""
    parts = [f"{len(snap['bodies'])} bodies", f"{snap['rate_hz']:8.1f} poses/s",
             f"published {snap['published']}", f"occluded {snap['occluded']}",
             f"dup {snap['duplicates']}", f"gaps {snap['gaps']}"]
    if "datagrams" in snap["source_counters"]:
        parts.insert(2, f"{snap['datagram_rate_hz']:7.1f} dgram/s")
        parts.append(f"malformed {snap['malformed']}")
    skipped = snap["source_counters"].get("skipped_items", 0)
    if skipped:
        parts.append(f"skipped items {skipped}")
    return "mocap: " + " | ".join(parts)
