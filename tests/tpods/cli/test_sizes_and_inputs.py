"""Issue 16: sizes checked from the options before anything is allocated, one --seed type,
inputs shorter than --duration, phase-sine duties named by their option."""

from __future__ import annotations

import argparse

import pytest

from common import sizes
from common.argtypes import SEED_MAX, random_seed
from common.errors import UserError
from tests.support.cli import run, run_in_process
from tpods.cli.estimate import check_sim_size


def _one_error_line(r) -> str:
    assert r.returncode == 2, (r.stdout, r.stderr)
    assert "Traceback" not in r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("tpods: error: "), r.stderr
    return lines[0]


@pytest.mark.parametrize("args,names", [
    (("--cmd-rate", "1e9"), ("--cmd-rate 1e9 Hz", "1.2e11 command rows", "lower --cmd-rate")),
    (("--duration", "1e9"), ("--duration 1e9 s", "1.2e11 poses", "5e10 command rows")),
    (("--pose-rate", "1e7"), ("--pose-rate 1e7 Hz", "1.2e9 poses", "lower --pose-rate")),
    (("--duration", "1e308"), ("--duration 1e308 s", "unbounded memory")),
])
def test_sim_refuses_what_will_not_fit_before_allocating(tpods_exe, tmp_path, args, names):
    r = run(tpods_exe, "sim", *args, "--out", str(tmp_path / "o"), timeout=60)
    line = _one_error_line(r)
    for n in names:
        assert n in line, line
    assert "memory; this machine has" in line
    assert not (tmp_path / "o").exists()


def test_refusal_is_against_half_the_available_memory():
    sizes.refuse_if_too_big("x", 4e9, "fix", memory=10e9)  # fits
    with pytest.raises(UserError, match=r"x \(needs ~6 GB memory; this machine has 10 GB available\): fix"):
        sizes.refuse_if_too_big("x", 6e9, "fix", memory=10e9)
    assert sizes.available_memory() > 0


def test_long_simulation_is_announced_short_one_is_not(capsys):
    ns = argparse.Namespace(pose_rate=3000.0, cmd_rate=50.0, duration=None, input="phase-sine")
    check_sim_size(ns, 120.0)
    err = capsys.readouterr().err
    assert err.startswith("tpods: simulating 360001 poses will take about ") and err.endswith(" s\n")
    ns.pose_rate = 120.0
    check_sim_size(ns, 120.0)
    assert capsys.readouterr().err == ""


def test_size_texts():
    assert sizes.number(1e9) == "1e9" and sizes.number(120.0) == "120" and sizes.number(1.2e11) == "1.2e11"
    assert sizes.size_text(9.6e13) == "96 TB" and sizes.size_text(2.4e9) == "2.4 GB"
    assert sizes.samples_text(1e308, 120.0) == "1.2e310"


def test_seed_type():
    assert random_seed("0") == 0 and random_seed(str(SEED_MAX)) == SEED_MAX
    for bad in ("-5", "1.5", "x", str(SEED_MAX + 1)):
        with pytest.raises(argparse.ArgumentTypeError, match="whole number in 0..4294967295"):
            random_seed(bad)


@pytest.mark.parametrize("cmd", [
    ("sim",), ("design",), ("estimate", "montecarlo"), ("report", "realism"), ("report", "table3"),
    ("bench", "emulate"), ("run", "plant"), ("demo",),
])
def test_every_seed_option_refuses_a_negative_seed(tpods_exe, tmp_path, cmd):
    r = run_in_process(*cmd, "--seed", "-5", "--out", str(tmp_path / "o"))
    line = _one_error_line(r)
    assert "argument --seed: must be a whole number in 0..4294967295, got '-5'" in line


def test_sim_input_shorter_than_duration(tpods_exe, tmp_path):
    short = tmp_path / "short"
    assert run_in_process("sim", "--duration", "3", "--out", str(short)).returncode == 0
    line = _one_error_line(run_in_process("sim", "--input", str(short / "commands.csv"),
                               "--duration", "60", "--out", str(tmp_path / "o")))
    assert "holds 3 s of commands" in line and "--duration 60 s" in line
    assert not (tmp_path / "o").exists()
    # without --duration the whole file; with a shorter one, cut
    r = run_in_process("sim", "--input", str(short), "--out", str(tmp_path / "whole"))
    assert r.returncode == 0 and "duration        3.00 s" in r.stdout, r.stderr
    r = run_in_process("sim", "--input", str(short), "--duration", "2", "--out", str(tmp_path / "cut"))
    assert r.returncode == 0 and "duration        2.00 s" in r.stdout, r.stderr


@pytest.mark.parametrize("args,expected", [
    (("--amplitude", "80"), "--amplitude 80 puts the phase-sine duties at -30..130 %, outside 0..100 %"),
    (("--amplitude", "45"), "--amplitude 45 puts the phase-sine duties at 5..95 %, outside the thrust "
                            "table's valid range 10-90 %: use --amplitude 40 or less, or add --clamp"),
])
def test_sim_amplitude_names_the_option(tpods_exe, tmp_path, args, expected):
    assert expected in _one_error_line(run_in_process("sim", *args, "--out", str(tmp_path / "o")))


def test_sim_clamp_and_omega_above_nyquist_warns(tpods_exe, tmp_path):
    r = run_in_process("sim", "--amplitude", "45", "--clamp", "--duration", "1", "--omega", "1000",
            "--out", str(tmp_path / "o"))
    assert r.returncode == 0, r.stderr
    assert "tpods: warning: --omega 1000 rad/s is above the Nyquist frequency of --cmd-rate 50 Hz" in r.stderr


def test_run_play_checks_duties_before_opening_the_valves(tpods_exe, tmp_path):
    # /dev/null is never opened: the duties are refused first
    line = _one_error_line(run_in_process("run", "play", "--valves", "/dev/null", "--amplitude", "45"))
    assert "--amplitude 45" in line and "--duty-limits 10,90" in line and "--amplitude 40 or less" in line


def test_crlb_refuses_planned_poses_that_will_not_fit(tpods_exe, tmp_path):
    """Was a silent hang (or a MemoryError traceback) at --pose-rate 1e7."""
    assert run_in_process("sim", "--duration", "3", "--out", str(tmp_path / "r")).returncode == 0
    line = _one_error_line(run(tpods_exe, "estimate", "crlb", str(tmp_path / "r" / "commands.csv"),
                               "--pose-rate", "1e7", timeout=60))
    assert "--pose-rate 1e7 Hz over the 3 s of" in line and "3e7 planned poses" in line
    assert "lower --pose-rate" in line


@pytest.mark.parametrize("args,needles", [
    (("--duration", "1e9"), ("--duration 1e9 s", "per candidate", "lower --duration")),
    (("--cmd-rate", "1e9"), ("--cmd-rate 1e9 Hz", "1.2e11 command rows per candidate")),
    (("--candidates", "100000"), ("100121 candidates (1 + --candidates 100000", "lower --candidates")),
])
def test_design_refuses_what_will_not_fit(tpods_exe, tmp_path, args, needles):
    line = _one_error_line(run(tpods_exe, "design", *args, "--out", str(tmp_path / "o"), timeout=60))
    for n in needles:
        assert n in line, line
    assert not (tmp_path / "o").exists()


def test_crlb_and_design_costs_scale_with_the_work():
    small_b, small_s = sizes.crlb_cost(sizes.crlb_segments(14401, 6001, 120.0), 2)
    big_b, big_s = sizes.crlb_cost(sizes.crlb_segments(144001, 6001, 120.0), 7)
    assert 1e6 < small_b < 1e9 and small_s < sizes.ANNOUNCE_S  # the default bound is quick
    assert big_b > 10 * small_b and big_s > 10 * small_s


def test_ls_window_longer_than_the_run_warns_naming_both(tpods_exe, tmp_path):
    assert run_in_process("sim", "--duration", "4", "--out", str(tmp_path / "r")).returncode == 0
    r = run_in_process("estimate", "batch", str(tmp_path / "r"), "--method", "ls-ekf", "--ls-window", "500")
    assert r.returncode == 0, r.stderr
    warn = [ln for ln in r.stderr.splitlines() if ln.startswith("tpods: warning: --ls-window")]
    assert warn == ["tpods: warning: --ls-window 500 s covers all of the run (4 s of poses): the LS start "
                    "uses every pose and the filter adds nothing to it; give --ls-window below 4 s, or "
                    "use --method ls"], r.stderr
    r = run_in_process("estimate", "batch", str(tmp_path / "r"), "--method", "ls-ekf", "--ls-window", "2")
    assert r.returncode == 0 and "--ls-window" not in r.stderr, r.stderr


def test_live_ls_window_not_shorter_than_duration_is_refused_before_listening(tpods_exe):
    line = _one_error_line(run_in_process("estimate", "live", "--method", "ls-ekf", "--duration",
                                          "5", "--ls-window", "10"))
    assert "--ls-window 10 s is not shorter than --duration 5 s" in line


@pytest.mark.parametrize("spec,needle", [
    ("udp:127.0.0.1:99999", "--mocap udp:127.0.0.1:99999: port 99999 is out of range (1-65535)"),
    ("udp:127.0.0.1:0", "port 0 is out of range"),
    ("udp:127.0.0.1", "--mocap must be udp:HOST:PORT"),
    ("udp:no-such-host.invalid:5000", "cannot resolve host 'no-such-host.invalid'"),
])
def test_run_plant_refuses_a_bad_udp_target_before_the_run(tpods_exe, spec, needle):
    """Was: status 0 and 'plant: 1 poses' (the sender's error swallowed in its thread)."""
    r = run_in_process("run", "plant", "--mocap", spec, "--duration", "1")
    line = _one_error_line(r)
    assert needle in line and "valves:" not in r.stdout


def test_run_plant_reports_a_plant_loop_error(monkeypatch, capsys):
    """An error inside the plant loop's thread ends the run at once with one line, status 2."""
    import tpods.plant_loop as pl
    from tpods.cli import main

    def broken_sink(*a, **k):
        def sink(*_a):
            raise OSError("network is unreachable")
        sink.close = lambda: None
        return sink

    monkeypatch.setattr(pl, "udp_sink", broken_sink)
    assert main(["run", "plant", "--mocap", "udp:127.0.0.1:5000", "--duration", "30"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == "tpods: error: the simulated module stopped after 1 poses: network is unreachable"
