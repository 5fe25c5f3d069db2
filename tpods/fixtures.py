"""Recorded fixtures (runs/fixtures/NAME/): what kind a recording is, its golden values,
and ``tpods fixture add``.

A fixture is a folder holding a recording, a ``README.md`` (what, when, from where, how to
regenerate), a ``fixture.json`` (``kind``, ``source``, ``added``, ``how``; the kind says how
to replay it) and ``golden/values.json``: named numbers (or lists of numbers) computed by
:func:`compute_goldens`, held to :data:`TOLERANCES` of their kind.
``tests/regression/test_fixtures_generic.py`` recomputes every fixture's values with the
same function and compares (tests/support/golden.py); the hand-written tests under
``tests/regression/`` replay the curated fixtures through more of the stack.

Kinds (:func:`detect_kind`):

- ``run``: a run folder (``poses.csv``, ``commands.csv``): batch LS, the JSON of
  ``tpods estimate batch`` (mass, izz and their sigmas).
- ``structure-run``: a run folder with ``structure.toml``: the same, plus the centre of mass.
- ``bifilar``: ``poses.csv`` of a swing and ``bifilar.json`` (``mass_kg``, ``spacing_m``,
  ``length_m``, optional ``u_mass_kg``, ``u_spacing_m``, ``u_length_m``): the trace fit of
  ``tpods calibrate bifilar --poses`` (Izz and its sigma).
- ``bench-session``: serial transcripts ``valves.serial.jsonl`` and ``scale.serial.jsonl``
  (``tpods bench characterize --capture``) with the session's configuration
  (``session.json`` or the session's ``run.json``): replayed strictly through the drivers,
  bench.session and bench.fit (thrust per step, the table's coefficients).
- ``pcap``: a Vicon Tracker UDP capture: every datagram through the Tracker parser
  (datagram and pose counters, per body: poses, occluded, mean x, y, z).
- ``mcap``: Zenoh streams in MCAP: messages per key, the last estimate's mass and izz.
"""

from __future__ import annotations

import json
import math
import shutil
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from common.errors import UserError

FIXTURES_ROOT = Path(__file__).resolve().parents[1] / "runs" / "fixtures"
GOLDEN_NAME = "values.json"

KINDS = {
    "run": "a run folder (poses.csv, commands.csv): golden batch LS mass, Izz, sigmas",
    "structure-run": "a structure run folder (structure.toml): golden batch LS mass, Izz, centre of mass, sigmas",
    "bifilar": "a bifilar swing (poses.csv, bifilar.json): golden Izz and sigma of the trace fit",
    "bench-session": "a bench session's serial transcripts (*.serial.jsonl): golden thrust per step and table",
    "pcap": "a Vicon Tracker UDP capture (pcap): golden datagram and pose counts, mean positions",
    "mcap": "Zenoh streams in MCAP: golden messages per key, last estimate",
}

# (atol, rtol) of each kind's golden values: the computations are deterministic on one
# machine (replays of the same bytes, fits of the same numbers); the relative margin
# covers a different BLAS or CPU summing in another order.
TOLERANCES: dict[str, tuple[float, float]] = {
    "run": (0.0, 1e-9), "structure-run": (0.0, 1e-9), "bifilar": (0.0, 1e-9),
    "bench-session": (1e-12, 0.0), "pcap": (1e-12, 0.0), "mcap": (0.0, 0.0),
}

_RUN_KEYS = ("mass_kg", "mass_sigma_kg", "izz_kgm2", "izz_sigma_kgm2")
_STRUCTURE_KEYS = _RUN_KEYS + ("com_x_m", "com_x_sigma_m", "com_y_m", "com_y_sigma_m")
BIFILAR_INPUTS = ("mass_kg", "spacing_m", "length_m")


def golden_path(fixture: Path) -> Path:
    return Path(fixture) / "golden" / GOLDEN_NAME


def replay_golden_path(fixture: Path) -> Path:
    """The live run's second golden: the final estimate of its MCAP replayed into
    ``tpods estimate live`` (tests/regression/test_live_run_fixture.py)."""
    return Path(fixture) / "golden" / "replay.json"


# --------------------------------------------------------------------------- kinds


def detect_kind(path: str | Path) -> str:
    """The kind of a recording (a key of :data:`KINDS`); UserError (one line) when it is
    none of them."""
    p = Path(path)
    if not p.exists():
        raise UserError(f"{p}: no such file or folder")
    if p.is_file():
        suffix = p.suffix.lower()
        if suffix in (".pcap", ".pcapng"):
            return "pcap"
        if suffix == ".mcap":
            return "mcap"
        raise UserError(f"{p}: not a recording this command knows (a run, structure run, bifilar "
                        "or bench session folder, a .pcap or a .mcap file)")
    names = {q.name for q in p.iterdir() if q.is_file()}
    if "poses.csv" in names and "commands.csv" in names:
        return "structure-run" if "structure.toml" in names else "run"
    if "poses.csv" in names and "bifilar.json" in names:
        return "bifilar"
    if "poses.csv" in names:
        raise UserError(f"{p}: poses.csv without commands.csv (a run) or bifilar.json (a bifilar "
                        "swing: mass_kg, spacing_m, length_m)")
    if any(n.endswith(".serial.jsonl") for n in names):
        return "bench-session"
    raise UserError(f"{p}: not a recording this command knows (no poses.csv, *.serial.jsonl, "
                    ".pcap or .mcap)")


# --------------------------------------------------------------------------- goldens


def _recording_file(fixture: Path, suffixes: tuple[str, ...]) -> Path:
    meta = read_fixture_json(fixture)
    if meta.get("file"):
        return fixture / meta["file"]
    found = sorted(q for q in fixture.iterdir() if q.suffix.lower() in suffixes)
    if not found:
        raise UserError(f"{fixture}: no {'/'.join(suffixes)} file")
    return found[0]


def _run_values(fixture: Path, keys: tuple[str, ...]) -> dict[str, Any]:
    from estimator.estimate import estimate_run

    table = fixture / "thrust_table.toml"
    est = estimate_run(fixture, table if table.exists() else None, method="ls", estimate=None).to_dict()
    return {k: est[k] for k in keys}


def _bifilar_values(fixture: Path) -> dict[str, Any]:
    import numpy as np

    from calibration.swing.bifilar import fit_swing_trace
    from common.runfolder import POSE_COLUMNS, read_table

    inputs = json.loads((fixture / "bifilar.json").read_text())
    missing = [k for k in BIFILAR_INPUTS if k not in inputs]
    if missing:
        raise UserError(f"{fixture / 'bifilar.json'}: missing {', '.join(missing)}")
    v = read_table(fixture / "poses.csv", POSE_COLUMNS)
    res = fit_swing_trace(np.ascontiguousarray(v[:, 0]), np.ascontiguousarray(v[:, 3]), inputs["mass_kg"],
                          inputs["spacing_m"], inputs["length_m"],
                          u_mass_kg=inputs.get("u_mass_kg", 1.44e-3),
                          u_spacing_m=inputs.get("u_spacing_m", 0.001),
                          u_length_m=inputs.get("u_length_m", 0.002))
    return {"izz_kgm2": res.izz_kgm2, "izz_sigma_kgm2": res.izz_sigma_kgm2}


def bifilar_cli_args(fixture: Path) -> list[str]:
    """The ``tpods calibrate bifilar`` arguments that give :func:`_bifilar_values`."""
    inputs = json.loads((Path(fixture) / "bifilar.json").read_text())
    return ["calibrate", "bifilar", "--poses", str(fixture), "--mass", repr(inputs["mass_kg"]),
            "--spacing", repr(inputs["spacing_m"]), "--length", repr(inputs["length_m"]),
            "--u-mass", repr(inputs.get("u_mass_kg", 1.44e-3)),
            "--u-spacing", repr(inputs.get("u_spacing_m", 0.001)),
            "--u-length", repr(inputs.get("u_length_m", 0.002))]


def _bench_config(fixture: Path):
    from bench.session import SessionConfig

    for name in ("session.json", "run.json"):
        f = fixture / name
        if f.exists():
            meta = json.loads(f.read_text())
            if "config" in meta:
                c = {k: tuple(v) if isinstance(v, list) else v for k, v in meta["config"].items()}
                fields = SessionConfig.__dataclass_fields__
                order = meta.get("fit_order")
                return SessionConfig(**{k: v for k, v in c.items() if k in fields}), order
    raise UserError(f"{fixture}: no session.json or run.json with the session's configuration "
                    "(tpods bench characterize writes run.json beside its --capture)")


def _bench_values(fixture: Path) -> dict[str, Any]:
    import tempfile

    from bench.fit import fit_steps
    from bench.ohaus.driver import OhausScout
    from bench.session import run_session
    from bench.valves import ValveController

    for n in ("valves.serial.jsonl", "scale.serial.jsonl"):
        if not (fixture / n).exists():
            raise UserError(f"{fixture}: no {n} (a bench session needs both transcripts)")
    config, order = _bench_config(fixture)
    if order is None:
        order = 1 if len(config.duties_pct) <= 3 else 2
    with tempfile.TemporaryDirectory() as tmp, \
            ValveController(f"replay://{fixture.resolve()}/valves.serial.jsonl") as valves, \
            OhausScout(f"replay://{fixture.resolve()}/scale.serial.jsonl") as scale:
        res = run_session(valves, scale, config, Path(tmp) / "replay", progress=False)
    if res.status != "success":
        raise UserError(f"{fixture}: the strict replay failed: {res.error}")
    table = fit_steps(res.steps, order=order).table(source=str(fixture))
    out: dict[str, Any] = {c: res.steps[c].astype(float).tolist() for c in ("n", "mean_raw_gf", "thrust_gf")}
    for k in sorted(table.coefficients):
        out[f"nozzles {k} coefficients"] = list(map(float, table.coefficients[k]))
    return out


def _pcap_values(fixture: Path) -> dict[str, Any]:
    from mocap_bridge.capture import PcapReader
    from mocap_bridge.sources.vicon_udp import DatagramDecoder

    path = _recording_file(fixture, (".pcap", ".pcapng"))
    reader = PcapReader(path)
    dec = DatagramDecoder(on_notice=lambda m: None)
    bodies: dict[str, list] = {}
    try:
        for d in reader:
            for s in dec.decode(d.payload, d.t_ns * 1e-9) or ():
                bodies.setdefault(s.body, []).append(s)
    finally:
        reader.close()
    out: dict[str, Any] = {f"decoder {k}": v for k, v in dec.counters.items()}
    out.update({f"reader {k}": v for k, v in reader.counters.items()})
    for body, ss in sorted(bodies.items()):
        seen = [s for s in ss if not s.occluded]
        out[f"{body} poses"] = len(ss)
        out[f"{body} occluded"] = len(ss) - len(seen)
        for ax in ("x", "y", "z"):
            out[f"{body} mean {ax}"] = (math.fsum(getattr(s, ax) for s in seen) / len(seen)) if seen else math.nan
    return out


def _mcap_values(fixture: Path) -> dict[str, Any]:
    from common.mcap.log import read_mcap

    path = _recording_file(fixture, (".mcap",))
    rec = read_mcap(path)
    out: dict[str, Any] = {}
    last_est = None
    for m in rec.messages:
        out[f"messages {m.topic}"] = out.get(f"messages {m.topic}", 0) + 1
        if m.topic.endswith("/estimate"):
            last_est = m
    if last_est is not None:
        try:
            est = json.loads(last_est.data)
            for k in ("mass_kg", "izz_kgm2"):
                if isinstance(est.get(k), (int, float)):
                    out[f"last estimate {k}"] = est[k]
        except (ValueError, AttributeError):
            pass
    return out


COMPUTE: dict[str, Callable[[Path], dict[str, Any]]] = {
    "run": lambda f: _run_values(f, _RUN_KEYS),
    "structure-run": lambda f: _run_values(f, _STRUCTURE_KEYS),
    "bifilar": _bifilar_values,
    "bench-session": _bench_values,
    "pcap": _pcap_values,
    "mcap": _mcap_values,
}


def compute_goldens(fixture: str | Path, kind: str | None = None) -> dict[str, Any]:
    """The named values a fixture's golden holds, computed from its recording now."""
    fixture = Path(fixture)
    kind = kind or read_fixture_json(fixture).get("kind") or detect_kind(fixture)
    if kind not in COMPUTE:
        raise UserError(f"{fixture}: unknown fixture kind {kind!r} (known: {', '.join(KINDS)})")
    return COMPUTE[kind](fixture)


def _as_json(values: dict[str, Any]) -> dict[str, Any]:
    return {k: (list(map(float, v)) if isinstance(v, (list, tuple)) else float(v)) for k, v in values.items()}


def write_goldens(fixture: str | Path, kind: str | None = None) -> list[str]:
    """Compute and write ``golden/values.json``; returns one line per golden written."""
    fixture = Path(fixture)
    path = golden_path(fixture)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(_as_json(compute_goldens(fixture, kind)), indent=1, sort_keys=True) + "\n")
    return [f"golden {path}: written"]


# --------------------------------------------------------------------------- fixture.json, add


def read_fixture_json(fixture: Path) -> dict[str, Any]:
    f = Path(fixture) / "fixture.json"
    return json.loads(f.read_text()) if f.exists() else {}


def write_fixture_json(fixture: Path, kind: str, *, source: str, how: str, file: str | None = None) -> None:
    meta = {"kind": kind, "source": source, "added": time.strftime("%Y-%m-%d %H:%M:%S %z"), "how": how}
    if file:
        meta["file"] = file
    (Path(fixture) / "fixture.json").write_text(json.dumps(meta, indent=1) + "\n")


def _copy_recording(src: Path, dest: Path, kind: str) -> str | None:
    """Copy what the kind needs; returns the recording's file name for one-file kinds."""
    dest.mkdir(parents=True)
    if src.is_file():
        shutil.copy2(src, dest / src.name)
        return src.name
    for q in sorted(src.iterdir()):
        if not q.is_file() or q.name in ("README.md", "fixture.json"):
            continue
        if kind == "bench-session" and not (q.name.endswith(".serial.jsonl")
                                            or q.name in ("run.json", "session.json")):
            continue
        shutil.copy2(q, dest / q.name)
    return None


def check_whole(src: Path, kind: str) -> None:
    """Refuse a recording that did not end cleanly: its golden would be of a mid-run state
    (an MCAP file cut by a kill or closed with a status other than complete or success;
    a run folder whose run.json says it is partial)."""
    from common.mcap.log import end_status
    from common.runfolder import WHOLE_STATUSES, partial_status

    why = "; record it again, or replay what it holds with tpods replay"
    if kind == "mcap":
        status = end_status(src)
        if status is None:
            raise UserError(f"{src}: the recording is cut (no summary and footer: the recorder "
                            f"was killed or the file truncated); a fixture needs a whole "
                            f"recording{why}")
        if status not in WHOLE_STATUSES:
            raise UserError(f"{src}: the recording ended with status {status!r}, not complete; "
                            f"a fixture needs a whole recording{why}")
    elif src.is_dir() and (src / "run.json").is_file():
        try:
            meta = json.loads((src / "run.json").read_text(encoding="utf-8-sig"))
        except (OSError, ValueError) as exc:
            raise UserError(f"{src / 'run.json'}: not valid JSON ({exc})") from None
        status = partial_status(meta)
        if status is not None:
            raise UserError(f"{src} is a partial run ({src / 'run.json'} says status "
                            f"{status!r}); a fixture needs a whole recording")


def add_fixture(recording: str | Path, name: str, *, root: str | Path = FIXTURES_ROOT,
                force: bool = False) -> tuple[Path, str, list[str]]:
    """Copy a recording into ``root/name``, write its README.md, fixture.json and goldens.

    Returns ``(folder, kind, golden lines)``. UserError (one line) on what it cannot do."""
    src = Path(recording)
    kind = detect_kind(src)
    check_whole(src, kind)
    if not name or "/" in name or name.startswith("."):
        raise UserError(f"fixture name {name!r}: use a plain folder name")
    root = Path(root)
    dest = root / name
    if dest.exists():
        if not force:
            raise UserError(f"{dest} already exists (add --force to replace it)")
        shutil.rmtree(dest)
    root.mkdir(parents=True, exist_ok=True)
    file = _copy_recording(src, dest, kind)
    how = f"tpods fixture add {src.resolve()} --name {name} --force" + (
        f" --root {root}" if root.resolve() != FIXTURES_ROOT.resolve() else "")
    write_fixture_json(dest, kind, source=str(src.resolve()), how=how, file=file)
    when = read_fixture_json(dest)["added"]
    (dest / "README.md").write_text(
        f"# {name}: {KINDS[kind].split(':')[0]}\n\n"
        f"{KINDS[kind]}. Added {when} by `tpods fixture add` from `{src.resolve()}`; regenerate "
        f"(recording and goldens) with `{how}`, or only the goldens with `make golden`. "
        f"tests/regression/test_fixtures_generic.py checks `golden/{GOLDEN_NAME}` (kind `{kind}`, "
        f"tolerance atol {TOLERANCES[kind][0]:g}, rtol {TOLERANCES[kind][1]:g}).\n")
    try:
        lines = write_goldens(dest, kind)
    except BaseException:
        shutil.rmtree(dest, ignore_errors=True)
        raise
    return dest, kind, lines


def list_fixtures(root: str | Path = FIXTURES_ROOT) -> list[Path]:
    """Fixture folders under ``root`` that have a fixture.json."""
    root = Path(root)
    return sorted(p.parent for p in root.glob("*/fixture.json")) if root.exists() else []
