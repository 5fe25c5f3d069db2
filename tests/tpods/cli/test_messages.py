"""Issue 16: no internal names in messages (Rust source paths, Rust enum reprs, Python
exception names) and no RuntimeWarnings on the terminal where they are expected."""

from __future__ import annotations

import warnings

from common.errors import UserError
from tests.support.cli import run_in_process
from tpods.cli import quiet_expected_warnings, user_message


def test_user_message_drops_internal_names():
    assert user_message(UserError(
        "cannot open the zenoh session (invalid port value at "
        "/root/.cargo/git/checkouts/zenoh-9c599d5ef3e0480e/cc83980/io/zenoh-link-commons/src/lib.rs:62.)")) == \
        "cannot open the zenoh session (invalid port value)"
    assert user_message(UserError(
        "cannot open the zenoh session (Unable to connect to any of [Single(tcp/127.0.0.1:1)]!  at "
        "/root/.cargo/git/x/zenoh/src/net/runtime/orchestrator.rs:447.)")) == \
        "cannot open the zenoh session (Unable to connect to any of tcp/127.0.0.1:1)"
    assert user_message(UserError("t.toml: malformed thrust table (KeyError: 'nozzles')")) == \
        "t.toml: malformed thrust table (missing key 'nozzles')"
    assert user_message(UserError("t.toml: malformed thrust table (ValueError: could not convert)")) == \
        "t.toml: malformed thrust table (could not convert)"
    plain = "runs/x: no such run folder"
    assert user_message(UserError(plain)) == plain


def test_cli_bad_zenoh_listen_port_is_plain(tpods_exe):
    r = run_in_process("estimate", "live", "--listen", "tcp/127.0.0.1:99999", "--duration", "1")
    assert r.returncode == 2
    assert r.stderr.strip() == "tpods: error: cannot open the zenoh session (invalid port value)", r.stderr


def test_cli_thrust_table_without_nozzles(tpods_exe, tmp_path):
    t = tmp_path / "t.toml"
    t.write_text('unit = "gf"\n')
    r = run_in_process("sim", "--duration", "1", "--thrust-table", str(t), "--out", str(tmp_path / "o"))
    assert r.returncode == 2 and "KeyError" not in r.stderr and "Traceback" not in r.stderr, r.stderr


def test_expected_numeric_warnings_are_quiet_on_the_terminal(tpods_exe, tmp_path):
    """An absurd initial guess overflows inside the fit; the command says so in words."""
    assert run_in_process("sim", "--duration", "3", "--out", str(tmp_path / "r")).returncode == 0
    r = run_in_process("estimate", "batch", str(tmp_path / "r"), "--initial", "m=1e-300")
    assert r.returncode == 2
    assert "RuntimeWarning" not in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert r.stderr.startswith("tpods: error: the initial guess gives a non-finite trajectory")


def test_quiet_filter_spares_other_warnings():
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        quiet_expected_warnings()
        warnings.warn_explicit("overflow encountered in square", RuntimeWarning, "x.py", 1,
                               module="estimator.batch.least_squares")
        warnings.warn_explicit("overflow encountered in square", RuntimeWarning, "x.py", 1,
                               module="someone_else")
        warnings.warn_explicit("a real problem", RuntimeWarning, "x.py", 1, module="estimator.x")
        warnings.warn_explicit("overflow encountered in matmul", RuntimeWarning, "x.py", 1,
                               module="numpy._core.einsumfunc")  # einsum called by the fit
    assert [str(w.message) for w in got] == ["overflow encountered in square", "a real problem"]


def test_clamp_option_named_where_the_command_has_it():
    exc = UserError("c.csv: duty 64 % is outside the thrust table's valid range 40-60 % "
                    "(use the clamp option to saturate)")
    assert user_message(exc, clamp=True).endswith("40-60 % (add --clamp to saturate)")
    assert user_message(exc, clamp=False).endswith("40-60 %")


def test_cli_estimate_names_clamp(tpods_exe, tmp_path):
    from pathlib import Path

    root = Path(__file__).resolve().parents[3]
    assert run_in_process("sim", "--duration", "2", "--out", str(tmp_path / "r")).returncode == 0
    t = tmp_path / "narrow.toml"
    t.write_text((root / "common" / "data" / "table2_60psi.toml").read_text()
                 .replace("duty_range = [10.0, 90.0]", "duty_range = [40.0, 60.0]"))
    for cmd in (("estimate", "batch"), ("estimate", "crlb")):
        r = run_in_process(*cmd, str(tmp_path / "r"), "--thrust-table", str(t))
        assert r.returncode == 2 and r.stderr.strip().endswith("(add --clamp to saturate)"), r.stderr
