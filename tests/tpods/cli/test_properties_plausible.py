"""Property-based CLI robustness, part 2: the plausibility kinds of issue 26.

The harness, profiles and base inputs are :mod:`tests.tpods.cli.test_properties`' (its
docstring states the contract every example must meet; ``make robustness`` runs both files
with the long profile). On top of the contract, each property asserts its rule of
:mod:`common.plausible`: an absurd Monte Carlo size or a duty of ``--input`` is refused
naming what to change; a pose far off any table is refused by file and line; a reversed duty
range is called reversed; an empty pan is refused and an implausible weighed mass warns; a
[uncertainty.nozzles.k] without its row is refused naming it; overlapping modules are
refused; a cut MCAP never becomes a fixture; a recorder never writes a non-finite time.
"""

from __future__ import annotations

import json
import math
import shutil

import tomli_w
from hypothesis import given
from hypothesis import strategies as st

from tests.tpods.cli import test_properties as _props
from tests.tpods.cli.test_properties import (
    CSV_DAMAGE,
    TABLE2,
    WEIRD_NUMBERS,
    apply_damage,
    check,
    examples,
    note,
    prepare_out,
    workdir,
)
from tpods.fixtures import FIXTURES_ROOT

base = _props.base  # the shared module-scoped fixture: valid small inputs and the work root


def last_line(stderr: str) -> str:
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    return lines[-1] if lines else ""


@examples(6)
@given(duration=st.one_of(st.sampled_from([*WEIRD_NUMBERS, "1e9", "1e12"]),
                          st.floats(0.2, 1.0).map(lambda x: f"{x:.3g}")),
       rate=st.sampled_from([None, None, "--pose-rate=1e9", "--cmd-rate=1e10", "--pose-rate=60"]),
       damages=st.one_of(st.none(), st.lists(CSV_DAMAGE, min_size=1, max_size=2)))
def test_montecarlo_sizes_and_inputs(base, duration, rate, damages):
    with workdir(base["work"]) as work:
        argv = ["estimate", "montecarlo", "--runs", "2", f"--duration={duration}"]
        if rate:
            argv.append(rate)
        if damages is not None:
            apply_damage(base["run"], work / "run", [("commands.csv", d) for d in damages])
            argv.append(f"--input={work / 'run' / 'commands.csv'}")
        rc, _, err = check(argv, work, protect=(base["run"],))
        line = last_line(err)
        if rc == 2 and "duty" in line:  # a duty of the file: named by file and line
            assert "commands.csv: line " in line, line
        if rc == 2 and "memory" in line:
            assert "lower --duration" in line, line


POSE_VALUES = st.one_of(st.sampled_from(["1e30", "-1e30", "1e300", "2e5", "-1e6", "3000", "0.5"]),
                        st.floats(-1e12, 1e12).map(lambda x: f"{x:.6g}"))


@examples(8)
@given(row=st.integers(0, 300), col=st.sampled_from([1, 2]), value=POSE_VALUES,
       method=st.sampled_from(["ls", "ekf"]))
def test_a_pose_far_off_the_table_is_refused_by_line(base, row, col, value, method):
    with workdir(base["work"]) as work:
        apply_damage(base["run"], work / "run", [("poses.csv", ("cell", row, col, value))])
        rc, _, err = check(["estimate", "batch", str(work / "run"), "--method", method], work,
                           protect=(base["run"],))
        if abs(float(value)) > 1e5:
            assert rc == 2 and f"poses.csv: line {row + 2}: " in last_line(err), err
            assert "is not a position on an air table" in last_line(err)


DUTY = st.one_of(st.sampled_from(["0", "10", "50", "90", "100", "-5", "150", "nan"]),
                 st.integers(0, 100).map(str))


@examples(15)
@given(lo=DUTY, hi=DUTY, step=st.sampled_from(["10", "20", "0", "-10"]),
       which=st.sampled_from(["--duty", "--duty-limits", "duty_range"]))
def test_a_reversed_duty_range_is_called_reversed(base, lo, hi, step, which):
    with workdir(base["work"]) as work:
        out_args, out = prepare_out(work, "fresh")
        if which == "duty_range":
            t = json.loads(json.dumps(TABLE2))
            t["duty_range"] = [float(lo), float(hi)]
            (work / "t.toml").write_text(tomli_w.dumps(t))
            argv = ["sim", "--duration", "1", "--thrust-table", str(work / "t.toml")]
        else:
            value = f"{lo}:{hi}:{step}" if which == "--duty" else f"{lo},{hi}"
            argv = ["bench", "characterize", "--valves", str(work / "no-valves"), "--scale",
                    str(work / "no-scale"), f"{which}={value}"]
        rc, _, err = check(argv + out_args, work, out, "fresh")
        reversed_ = float(lo) > float(hi) and (which != "--duty" or float(step) > 0)
        if reversed_:
            assert rc == 2 and "is reversed (LOW above HIGH)" in last_line(err), err
        else:
            assert "reversed" not in err


READING = st.one_of(st.floats(-1.0, 5.0), st.floats(5.0, 2000.0), st.floats(1e5, 1e7))


@examples(20)
@given(values=st.lists(READING, min_size=2, max_size=4),
       unit=st.sampled_from(["g", "g", "kg", "lb", "mg"]),
       accuracy=st.sampled_from([None, "0", "0.1", "2.5", "50"]))
def test_calibrate_mass_empty_pans_and_implausible_masses(base, values, unit, accuracy):
    from calibration.mass import UNIT_TO_KG

    with workdir(base["work"]) as work:
        argv = ["calibrate", "mass", "--values=" + ",".join(f"{v:.6g}" for v in values),
                f"--unit={unit}", "--json"]
        if accuracy is not None:
            argv.append(f"--accuracy-g={accuracy}")
        rc, out, err = check(argv, work)
        kg = [float(f"{v:.6g}") * UNIT_TO_KG[unit] for v in values]
        a_kg = float(accuracy if accuracy is not None else 2.5) * 1e-3
        mean = sum(kg) / len(kg)
        if all(k > 0 for k in kg) and 0 < a_kg and mean <= a_kg * (1 - 1e-9):
            assert rc == 2 and "pan empty" in last_line(err), err
        if rc == 0:
            mass = json.loads(out)["mass_kg"]
            if not 0.05 <= mass <= 200.0:
                assert "tpods: warning: mass" in err and "implausible" in err, err


@examples(6)
@given(k=st.integers(0, 6), drop=st.sampled_from([None, "2", "3", "4"]))
def test_an_uncertainty_entry_needs_its_nozzle_row(base, k, drop):
    with workdir(base["work"]) as work:
        t = json.loads(json.dumps(TABLE2))
        if drop:
            t["nozzles"].pop(drop)
        t["uncertainty"] = {"scale_rel": 0.01, "nozzles": {str(k): {"scale_rel": 0.02}}}
        (work / "t.toml").write_text(tomli_w.dumps(t))
        out_args, out = prepare_out(work, "fresh")
        rc, _, err = check(["sim", "--duration", "1", "--thrust-table", str(work / "t.toml"),
                            *out_args], work, out, "fresh")
        if str(k) not in t["nozzles"]:
            assert rc == 2 and f"[uncertainty.nozzles.{k}]: the table has no" in last_line(err), err
        elif drop is None:
            assert rc == 0, err


POS = st.tuples(st.floats(-0.3, 0.3), st.floats(-0.3, 0.3)).map(lambda p: [round(p[0], 3),
                                                                            round(p[1], 3)])


@examples(8)
@given(positions=st.lists(POS, min_size=2, max_size=3),
       yaws=st.lists(st.sampled_from([0.0, 45.0, 90.0]), min_size=3, max_size=3))
def test_overlapping_modules_are_refused(base, positions, yaws):
    with workdir(base["work"]) as work:
        doc = {"name": "s", "modules": [{"name": f"m{i}", "position_m": p, "yaw_deg": y}
                                        for i, (p, y) in enumerate(zip(positions, yaws[:len(positions)], strict=True))]}
        (work / "s.toml").write_text(tomli_w.dumps(doc))
        out_args, out = prepare_out(work, "fresh")
        rc, _, err = check(["sim", "--duration", "1", "--structure", str(work / "s.toml"),
                            *out_args], work, out, "fresh")
        closest = min(math.dist(a, b) for i, a in enumerate(positions) for b in positions[:i])
        if closest < 0.1 - 1e-9:
            assert rc == 2 and "they would overlap" in last_line(err), err
        elif closest > 0.1 + 1e-9:
            assert "overlap" not in err


@examples(8)
@given(fraction=st.floats(0.0, 0.999))
def test_a_cut_mcap_never_becomes_a_fixture(base, fraction):
    full = FIXTURES_ROOT / "live-run" / "recording.mcap"
    with workdir(base["work"]) as work:
        cut = work / "cut.mcap"
        cut.write_bytes(full.read_bytes()[: int(full.stat().st_size * fraction)])
        rc, _, err = check(["fixture", "add", str(cut), "--name", "f", "--root", str(work / "fx")],
                           work, work / "fx", "fresh")
        assert rc == 2, err
        assert not (work / "fx" / "f").exists()


TIMES = st.one_of(st.sampled_from([math.nan, math.inf, -math.inf, 1e308, -1e308, 0.0]),
                  st.floats(-1e9, 1e9))


@examples(20)
@given(t0=st.one_of(st.none(), TIMES), times=st.lists(TIMES, min_size=1, max_size=5))
def test_the_recorder_never_writes_a_non_finite_time(base, t0, times):
    from common.errors import UserError
    from common.wire import encode_pose
    from mocap_bridge.recorder import Recorder

    with workdir(base["work"]) as work:
        try:
            rec = Recorder(work / "rec", t0=t0)
        except UserError:
            assert not math.isfinite(t0)
            return
        for k, t in enumerate(times):
            try:
                payload = encode_pose("m", k + 1, t, t, (0.1, 0.2, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0))
            except (ValueError, OverflowError):
                continue
            rec.handle(payload)
        rec.close()
        f = work / "rec" / "m" / "poses.csv"
        if f.exists():
            for line in f.read_text().splitlines()[1:]:
                note(line)
                assert math.isfinite(float(line.split(",")[0])), line
        shutil.rmtree(work / "rec")
