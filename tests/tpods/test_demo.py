"""``tpods demo --quick``: the whole lab day end to end (about 45 s)."""

from __future__ import annotations

import json
import subprocess


def test_demo_quick_writes_the_report(tpods_exe, tmp_path):
    out = tmp_path / "demo"
    r = subprocess.run([tpods_exe, "demo", "--quick", "--out", str(out)], capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "summary" in r.stdout and "time scale 2" in r.stdout
    s = json.loads((out / "summary.json").read_text())
    rows = {row["source"]: row for row in s["rows"]}
    assert set(rows) >= {"truth (simulation)", "balance + bifilar", "batch LS (recorded run)",
                         "batch LS, true table (check)"}
    # the ground-truth instruments and the batch fit with the true table find the truth
    assert abs(rows["balance + bifilar"]["mass_error_sigmas"]) < 3
    assert abs(rows["balance + bifilar"]["izz_error_sigmas"]) < 3
    chk = rows["batch LS, true table (check)"]
    assert abs(chk["mass_error_pct"]) < 1 and abs(chk["izz_error_pct"]) < 1
    assert s["live"]["play"]["valves_closed_confirmed"] is True
    report = (out / "report.md").read_text()
    figs = [line.split("(")[1].rstrip(")") for line in report.splitlines() if line.startswith("![")]
    assert len(figs) >= 6 and all((out / f).is_file() for f in figs)
