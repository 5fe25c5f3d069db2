"""A round-trip (ping) measurement of another host's clock over Zenoh, NTP-style.

The answering side (``tpods run play``, on the player's host) declares a queryable on
``<prefix>/<body>/clock`` (:func:`serve_clock`) that answers every query with its host
clock (``{"t": s}``). The asking side (:func:`ping_clock`) stamps the query's send time
``t_send`` and the answer's receipt ``t_recv`` on its own clock; each exchange gives

    offset = t_remote - (t_send + t_recv) / 2      (remote clock minus this one)

exact when the two ways take equal time, and off by at most half the round trip
``t_recv - t_send`` otherwise. :func:`ping_estimate` keeps the exchanges with the smallest
round trips (the least-queued, a quarter of them, at least 3), takes their median, and as
its sigma their spread (1.4826 MAD, at least a tenth of the smallest half round trip), and
reports the smallest round trip beside it: the bound on the ways' asymmetry.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

CLOCK_SCHEMA = "tpods.clock/1"


def clock_key(body: str, prefix: str = "tpods") -> str:
    """The key a player's clock answers on."""
    return f"{prefix.strip('/')}/{body}/clock"


@dataclass(frozen=True)
class PingEstimate:
    """Remote clock minus this one (s), its sigma (s), the smallest round trip (s), and the
    exchanges it rests on (kept of answered)."""

    offset_s: float
    sigma_s: float
    rtt_min_s: float
    kept: int
    answered: int

    def as_dict(self) -> dict[str, float | int]:
        return {"offset_ms": 1e3 * self.offset_s, "sigma_ms": 1e3 * self.sigma_s,
                "rtt_min_ms": 1e3 * self.rtt_min_s, "kept": self.kept, "answered": self.answered}


def _median(x: Sequence[float]) -> float:
    s = sorted(x)
    n = len(s)
    return s[n // 2] if n % 2 else 0.5 * (s[n // 2 - 1] + s[n // 2])


def ping_estimate(samples: Sequence[tuple[float, float, float]], keep: float = 0.25
                  ) -> PingEstimate | None:
    """The offset from ``(t_send, t_remote, t_recv)`` exchanges (s; see the module notes);
    None with fewer than 3 usable. Exchanges with a negative or non-finite round trip are
    skipped."""
    ok = [(r - s, t - 0.5 * (s + r)) for s, t, r in samples
          if all(math.isfinite(v) for v in (s, t, r)) and r >= s]
    if len(ok) < 3:
        return None
    ok.sort()
    kept = ok[:max(3, int(math.ceil(keep * len(ok))))]
    offs = [o for _, o in kept]
    med = _median(offs)
    mad = _median([abs(o - med) for o in offs])
    rtt_min = kept[0][0]
    return PingEstimate(med, max(1.4826 * mad, 0.05 * rtt_min), rtt_min, len(kept), len(ok))


def serve_clock(session: Any, key: str, clock: Callable[[], float] = time.time) -> Any:
    """Declare the queryable that answers with ``clock()`` (s); returns it (undeclare it)."""

    def answer(query: Any) -> None:
        query.reply(key, json.dumps({"schema": CLOCK_SCHEMA, "t": clock()}))

    return session.declare_queryable(key, answer)


def exchange(session: Any, key: str, timeout_s: float = 1.0,
             clock: Callable[[], float] = time.time) -> tuple[float, float, float] | None:
    """One exchange ``(t_send, t_remote, t_recv)`` (s) with the clock on ``key``; None when
    unanswered or malformed."""
    t_send = clock()
    try:
        replies = list(session.get(key, timeout=timeout_s))
    except Exception:  # a closed session or a refused query: no exchange
        return None
    t_recv = clock()
    for reply in replies[:1]:
        ok = getattr(reply, "ok", None)
        try:
            return t_send, float(json.loads(ok.payload.to_string())["t"]), t_recv
        except (AttributeError, KeyError, TypeError, ValueError):
            return None
    return None


def ping_clock(session: Any, key: str, n: int = 20, timeout_s: float = 1.0,
               clock: Callable[[], float] = time.time) -> PingEstimate | None:
    """``n`` exchanges with the clock on ``key``; None when fewer than 3 were answered
    (nobody serves it: it gives up after the first 2 unanswered)."""
    samples: list[tuple[float, float, float]] = []
    for i in range(n):
        x = exchange(session, key, timeout_s, clock)
        if x is not None:
            samples.append(x)
        elif not samples and i >= 1:
            break
    return ping_estimate(samples)


class PingPoller:
    """Exchanges with the clock on ``key`` every ``period_s`` seconds in a thread, for a
    whole run (the player may start after the estimator and end before it)."""

    def __init__(self, session: Any, key: str, period_s: float = 0.5,
                 timeout_s: float = 0.5) -> None:
        import threading

        self.session, self.key, self.period_s, self.timeout_s = session, key, period_s, timeout_s
        self.samples: list[tuple[float, float, float]] = []
        self.asked = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="clock-ping", daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            self.asked += 1
            x = exchange(self.session, self.key, self.timeout_s)
            if x is not None:
                self.samples.append(x)
            self._stop.wait(self.period_s)

    def __enter__(self) -> PingPoller:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=self.timeout_s + 1.0)

    def estimate(self) -> PingEstimate | None:
        """:func:`ping_estimate` of the exchanges so far."""
        return ping_estimate(list(self.samples))

    def summary(self) -> dict[str, Any]:
        """For a summary: the key, exchanges asked and answered, and the estimate (remote
        clock minus this host's, ms) or None."""
        e = self.estimate()
        return {"key": self.key, "asked": self.asked, "answered": len(self.samples),
                **({"offset_ms": None} if e is None else e.as_dict())}
