"""``tpods fixture add``: a fresh ``tpods sim`` run (and the other kinds of recording) added
to a temporary fixtures root passes the generic regression check; a changed golden fails it
with a readable message; what the command cannot recognise is refused in one line."""

import json

import pytest

from tests.support.cli import run_in_process
from tests.support.fixture_check import check_fixture
from tests.support.golden import GoldenMismatch
from tpods.fixtures import FIXTURES_ROOT, golden_path, read_fixture_json


def _add(exe, recording, name, root, *extra):
    return run_in_process("fixture", "add", str(recording), "--name", name, "--root", str(root), *extra)


def test_a_fresh_sim_run_becomes_a_fixture_the_generic_check_passes_and_a_changed_golden_fails(
        tpods_exe, tmp_path):
    r = run_in_process("sim", "--duration", "8", "--seed", "3", "--out", str(tmp_path / "sim-1"))
    assert r.returncode == 0, r.stderr
    root = tmp_path / "fixtures"
    r = _add(tpods_exe, tmp_path / "sim-1", "my-run", root)
    assert r.returncode == 0, r.stderr
    first = r.stdout.splitlines()[0]
    assert first.startswith(f"{tmp_path / 'sim-1'}: a run folder"), first
    fx = root / "my-run"
    assert read_fixture_json(fx)["kind"] == "run"
    assert {"poses.csv", "commands.csv", "run.json", "README.md", "fixture.json"} <= {p.name for p in fx.iterdir()}
    readme = (fx / "README.md").read_text()
    assert readme.startswith("# my-run") and str(tmp_path / "sim-1") in readme and "tpods fixture add" in readme
    check_fixture(fx)  # passes as written

    values = json.loads(golden_path(fx).read_text())
    values["mass_kg"] += 1e-3
    golden_path(fx).write_text(json.dumps(values, indent=1, sort_keys=True) + "\n")
    with pytest.raises(GoldenMismatch) as exc:
        check_fixture(fx)
    msg = str(exc.value)
    assert "fixture my-run (run) differs from its golden" in msg
    assert "mass_kg[0]: golden" in msg and "moved -0.001" in msg and "--update-goldens" in msg
    assert "izz_kgm2" not in msg  # only what moved is listed

    again = _add(tpods_exe, tmp_path / "sim-1", "my-run", root)
    assert again.returncode == 2 and again.stderr.startswith("tpods: error: ") and "--force" in again.stderr
    assert _add(tpods_exe, tmp_path / "sim-1", "my-run", root, "--force").returncode == 0
    check_fixture(fx)


@pytest.mark.parametrize("source, kind", [
    ("bench-session", "bench-session"),
    ("vicon-tracker/tracker.pcap", "pcap"),
    ("live-run/recording.mcap", "mcap"),
    ("bifilar-swing", "bifilar"),
    ("structure-run", "structure-run"),
])
def test_each_kind_is_detected_and_its_goldens_check(tpods_exe, tmp_path, source, kind):
    r = _add(tpods_exe, FIXTURES_ROOT / source, "f", tmp_path)
    assert r.returncode == 0, r.stderr
    assert len(r.stdout.splitlines()[0].splitlines()) == 1
    assert read_fixture_json(tmp_path / "f")["kind"] == kind
    check_fixture(tmp_path / "f")


def test_what_it_cannot_recognise_is_refused_in_one_line(tpods_exe, tmp_path):
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "a.txt").write_text("x")
    (tmp_path / "only-poses").mkdir()
    (tmp_path / "only-poses" / "poses.csv").write_text("t,x,y,psi\n0,0,0,0\n")
    for bad in (tmp_path / "notes", tmp_path / "notes" / "a.txt", tmp_path / "only-poses",
                tmp_path / "missing"):
        r = _add(tpods_exe, bad, "f", tmp_path / "root")
        assert r.returncode == 2, (bad, r.stdout)
        assert r.stderr.startswith("tpods: error: ") and len(r.stderr.splitlines()) == 1, r.stderr
        assert not (tmp_path / "root" / "f").exists()
