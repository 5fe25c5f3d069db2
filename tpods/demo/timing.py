"""The wall time of a demo's stages (``tpods demo`` and ``tpods demo --structure``): each
stage's banner and time as it ends, and the table of them in the printed summary, in
``report.md``, ``summary.json`` and the folder's ``run.json`` (``timings_s``), with the part
of each stage that is paced (lab time played at the time scale, the bench session's planned
settle and dwell windows) rather than computed.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator
from pathlib import Path


class StageTimes:
    """The stages of one demo in order: ``with times.stage(title, key): ...`` prints the
    banner and, at the end, the stage's wall time; :meth:`paced` notes the part of a stage
    that is waiting by design; ``meta`` (run.json's) gets ``timings_s`` after each stage."""

    def __init__(self, meta: dict | None = None) -> None:
        self.t0 = time.monotonic()
        self.wall_s: dict[str, float] = {}
        self.paced_s: dict[str, float] = {}
        self.side_s: dict[str, float] = {}
        """Work done in side processes beside the stages (:meth:`beside`), s by label."""
        self.meta = meta
        """run.json's metadata (:func:`common.runwriter.run_status`): its ``timings_s``
        follows every stage's end, so a partial lab day says how far it got and when."""

    @contextlib.contextmanager
    def stage(self, title: str | None, key: str) -> Iterator[None]:
        """One stage: ``title`` printed as its banner (None: a quiet stage, e.g. the figures)."""
        if title is not None:
            print(f"\n== {title}", flush=True)
        t = time.monotonic()
        try:
            yield
        finally:
            self.wall_s[key] = time.monotonic() - t
            if self.meta is not None:
                self.meta["timings_s"] = self.timings()
        if title is not None:
            print(f"   ({key}: {self.wall_s[key]:.1f} s)", flush=True)

    def paced(self, key: str, seconds: float) -> None:
        """``seconds`` of stage ``key`` are paced by design (lab time, planned windows)."""
        self.paced_s[key] = self.paced_s.get(key, 0.0) + float(seconds)

    def beside(self, side_s: dict[str, float]) -> None:
        """Wall time of the jobs that ran in side processes beside the stages (each label
        says beside which): rows of their own in the table, not in the total (they overlap
        the stages), and run.json's ``side_s``."""
        self.side_s.update(side_s)
        if self.meta is not None:
            self.meta["side_s"] = dict(self.side_s)

    def timings(self) -> dict[str, float]:
        """Every stage's wall time and the ``total`` so far, s (``summary.json``'s
        ``timings_s``)."""
        return {**self.wall_s, "total": time.monotonic() - self.t0}

    def lines(self, markdown: bool = False) -> list[str]:
        """The table of the stages: wall time, the paced part and the rest, s."""
        tim = self.timings()
        hdr = ["stage", "wall [s]", "paced [s]", "rest [s]"]
        body = []
        for k, v in tim.items():
            p = self.paced_s.get(k) if k != "total" else sum(self.paced_s.values())
            if k == "total":
                body += [[f"  {label}", f"({w:.1f})", "-", "-"] for label, w in self.side_s.items()]
            body.append([k, f"{v:.1f}", "-" if p is None else f"{p:.1f}",
                         "-" if p is None else f"{v - p:.1f}"])
        return table_text(hdr, body, markdown)


def table_text(hdr: list[str], body: list[list[str]], markdown: bool = False) -> list[str]:
    """A table as fixed-width text lines (first column left-aligned) or markdown lines."""
    if markdown:
        return (["| " + " | ".join(hdr) + " |", "|" + "---|" * len(hdr)]
                + ["| " + " | ".join(b) + " |" for b in body])
    w = [max(len(x[i]) for x in [hdr, *body]) for i in range(len(hdr))]
    return ["  ".join(x[i].rjust(w[i]) if i else x[i].ljust(w[i]) for i in range(len(hdr)))
            for x in [hdr, *body]]


def print_summary(title: str, rows: list[str], times: StageTimes, run_line: str, report,
                  n_figures: int) -> None:
    """The demo's last words: the summary table, the stages' wall times, the whole demo's
    time and where the report is."""
    print(f"\n== {title}\n")
    for line in rows:
        print("  " + line)
    print("\n== wall time of the stages (paced: the lab time played at the time scale, the "
          "bench session's planned windows" + ("; in parentheses: side processes beside the "
                                               "stages" if times.side_s else "") + ")\n")
    for line in times.lines():
        print("  " + line)
    print(f"\n{run_line}; whole demo {times.timings()['total']:.0f} s")
    print(f"report: {report} ({n_figures} figures)")


def write_report_md(out: Path, lines: list[str], times: StageTimes) -> Path:
    """``out/report.md``: ``lines`` and, last, the section on the stages' wall times."""
    path = out / "report.md"
    path.write_text("\n".join([*lines, *timing_section(times)]))
    return path


def timing_section(times: StageTimes) -> list[str]:
    """The report's section on the stages' wall times (markdown lines)."""
    return ["## Timing", "",
            "Wall time of each stage; paced: the lab time played at the time scale and the "
            "bench session's planned settle and dwell windows (waiting by design); rest: "
            "start-up of the processes, fits, figures. Indented rows in parentheses: work done "
            "in a side process beside the stages it names (not part of the total).", "",
            *times.lines(markdown=True), ""]
