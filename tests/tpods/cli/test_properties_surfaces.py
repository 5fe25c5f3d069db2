"""Property-based robustness of the newer surfaces, with the harness of test_properties.py
(exit 0 or 2, no traceback, one ``tpods: error:`` line, nothing changed outside ``--out``):
vehicle files with drawn values, command and pose logs in the shapes labs write them
(separators, decimal commas, 0/1 states, extra columns, shifted clocks), and swing logs (noise,
periods and rates in the wrong unit). Bounded in ``make test``; ``make robustness`` runs 25x
the examples."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from tests.tpods.cli import test_properties as _props
from tests.tpods.cli.test_properties import check, examples, workdir

base = _props.base
EIGHT = Path(__file__).resolve().parents[3] / "vehicles" / "example-8-onoff.toml"
NUMBERS = st.one_of(st.sampled_from(["0", "-1", "1e-9", "1e9", "nan", "inf", "0.44", "440", "4414"]),
                    st.floats(1e-6, 1e6).map(lambda x: f"{x:.6g}"))


def last_line(stderr: str) -> str:
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    return lines[-1] if lines else ""


@examples(8)
@given(key=st.sampled_from(["force_n", "force_sigma_n", "delay_s", "rise_s"]), value=NUMBERS)
def test_vehicle_file_values(base, key, value):
    with workdir(base["work"]) as work:
        text = EIGHT.read_text()
        text = re.sub(rf"^{key} = [^\n]*", f"{key} = {value}", text, count=1, flags=re.M)
        v = work / "v.toml"
        v.write_text(text)
        out = work / "D"
        rc, _, err = check(["design", "--vehicle", str(v), "--mass", "23", "--izz", "0.3",
                            "--candidates", "1", "--refine", "0", "--duration", "5", "--out",
                            str(out)], work, out=out, out_mode="fresh")
        x = float(value)
        if key == "force_n" and math.isfinite(x) and not 1e-3 <= x <= 50:
            assert rc == 2 and "force_n" in last_line(err), err
        if key in ("delay_s", "rise_s") and math.isfinite(x) and x > 2:
            assert rc == 2 and key in last_line(err), err


LOG_SHAPES = st.sampled_from(["comma", "semicolon-decimal-comma", "states-as-duty", "extra-column",
                              "shifted-clock", "tab"])


def _log(work: Path, shape: str, t0: float) -> tuple[Path, list[str]]:
    t = t0 + 0.1 * np.arange(30)
    duty = np.zeros((30, 8))
    duty[np.arange(30), np.arange(30) % 8] = 1.0
    sep = {"semicolon-decimal-comma": ";", "tab": "\t"}.get(shape, ",")
    cols = [f"v{i}" for i in range(1, 9)] + (["v9"] if shape == "extra-column" else [])
    rows = [sep.join([f"{a:.2f}", *(f"{x:g}" for x in r)] + (["0"] if shape == "extra-column" else []))
            for a, r in zip(t, duty, strict=True)]
    if shape == "semicolon-decimal-comma":
        rows = [r.replace(".", ",") for r in rows]
    f = work / "log.csv"
    f.write_text(sep.join(["time", *cols]) + "\n" + "\n".join(rows) + "\n")
    colmap = "t=time," + ",".join(f"d{i}=v{i}" for i in range(1, 9))
    form = "duty" if shape == "states-as-duty" else "columns"
    return f, ["--columns", colmap, "--as", form]


@examples(8)
@given(shape=LOG_SHAPES, t0=st.sampled_from([0.0, 0.05, 1e3, 1e9]),
       first=st.sampled_from(["poses", "commands"]))
def test_command_logs_into_a_run(base, shape, t0, first):
    with workdir(base["work"]) as work:
        log, opts = _log(work, shape, t0)
        poses = work / "poses.csv"
        t = 0.05 * np.arange(60)
        np.savetxt(poses, np.column_stack([t, 0.01 * t, 0 * t, 0 * t]), delimiter=",",
                   comments="", header="time,x,y,yaw", fmt="%.6f")
        out = work / "RUN"
        steps = {"poses": ["import", "poses", str(poses), "--out", str(out), "--columns",
                           "t=time,x=x,y=y,yaw=yaw", "--units", "m,rad", "--time-unit", "s"],
                 "commands": ["import", "commands", str(log), "--out", str(out), "--vehicle",
                              str(EIGHT), "--time-unit", "s", *opts]}
        order = [first, "commands" if first == "poses" else "poses"]
        codes = []
        for name in order:
            rc, _, err = check(steps[name], work, out=out,
                               out_mode="fresh" if not out.exists() else "force")
            codes.append(rc)
            if rc == 2:
                break
        if shape == "states-as-duty":
            assert 2 in codes and "0/1 valve states" in last_line(err), err
        if 2 in codes and out.exists() and not any(out.iterdir()):
            raise AssertionError("a refused import left an empty --out folder")


SWINGS = st.sampled_from(["clean", "noise", "deg-as-rad", "ms-as-s", "semicolon-decimal-comma"])


@examples(6)
@given(kind=SWINGS, seed=st.integers(0, 100))
def test_swing_logs(base, kind, seed):
    with workdir(base["work"]) as work:
        rng = np.random.default_rng(seed)
        w = 2 * math.pi / rng.uniform(1.0, 4.0)
        t = 0.01 * np.arange(2500)
        rate = 0.15 * w * np.cos(w * t) * np.exp(-0.01 * t) + rng.normal(0, 1e-3, len(t))
        if kind == "noise":
            rate = rng.normal(0, 0.01, len(t))
        if kind == "deg-as-rad":
            rate = np.degrees(rate)
        tt = t * 1000 if kind == "ms-as-s" else t
        sep = ";" if kind == "semicolon-decimal-comma" else ","
        body = "\n".join(f"{a:.4f}{sep}{b:.6f}" for a, b in zip(tt, rate, strict=True))
        if kind == "semicolon-decimal-comma":
            body = body.replace(".", ",")
        f = work / "g.csv"
        f.write_text(f"t{sep}rate\n{body}\n")
        rc, _, err = check(["calibrate", "bifilar", "--mass", "0.72", "--spacing", "0.2",
                            "--length", "1.0", "--rates", str(f)], work)
        words = {"noise": "does not oscillate", "deg-as-rad": "--rate-unit deg/s",
                 "ms-as-s": "--time-unit ms"}.get(kind)
        if words:
            assert rc == 2 and words in last_line(err), err
        else:
            assert rc == 0, err
