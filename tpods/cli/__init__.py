"""The ``tpods`` command line: a thin shell over the packages.

Each command group has a module here (``bench``, ``calibrate``, ``mocap``, ``run``; the
estimator's in :mod:`tpods.cli.estimate` until it moves) with ``register(subparsers)``: it
parses arguments, calls the packages and prints. Handlers return an exit status. User errors
(:class:`common.errors.UserError`) print one line and exit 2; Ctrl-C exits 130.

What the command modules share, they import from modules that import none of them:
:mod:`tpods.cli.parser` (the parser class, :func:`group`), :mod:`tpods.cli.options` (option
families written once), :mod:`tpods.cli.stopping` (signals, the Zenoh session, the valve
commands' exit) and :mod:`tpods.cli.estimate_output` (the estimate commands' output).
"""

from __future__ import annotations

import argparse
import re
import sys

import tpods
from common.errors import UserError
from tpods.cli.parser import Parser as _Parser
from tpods.cli.parser import group  # noqa: F401 - re-exported: ``from tpods.cli import group``


def build_parser() -> argparse.ArgumentParser:
    from tpods.cli.bench import register as register_bench
    from tpods.cli.calibrate import register as register_calibration
    from tpods.cli.estimate import register as register_estimator
    from tpods.cli.export import register as register_export
    from tpods.cli.fixture import register as register_fixture
    from tpods.cli.imports import register as register_import
    from tpods.cli.mocap import register as register_mocap
    from tpods.cli.net import register as register_net
    from tpods.cli.replay import register as register_replay
    from tpods.cli.run import register as register_run
    from tpods.cli.view import register as register_view
    from tpods.demo.lab_day import register as register_demo

    parser = _Parser(
        prog="tpods",
        description="TPODS lab-bench toolkit: thrust characterisation, ground-truth inertia, "
                    "mocap bridge, mass and Izz estimation.",
    )
    parser.add_argument("--version", action="version", version=f"tpods {tpods.__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    register_estimator(sub)
    register_bench(sub)
    register_calibration(sub)
    register_mocap(sub)
    register_run(sub)
    register_replay(sub)
    register_export(sub)
    register_import(sub)
    register_fixture(sub)
    register_view(sub)
    register_net(sub)
    register_demo(sub)
    return parser


def _value_options(parser: argparse.ArgumentParser) -> set[str]:
    """Long options that take a value in every sub-command that has them."""
    takes: dict[str, bool] = {}

    def walk(p: argparse.ArgumentParser) -> None:
        for a in p._actions:
            if isinstance(a, argparse._SubParsersAction):
                for sp in a.choices.values():
                    walk(sp)
                continue
            for opt in a.option_strings:
                if opt.startswith("--"):
                    takes[opt] = takes.get(opt, True) and a.nargs != 0
    walk(parser)
    return {o for o, v in takes.items() if v}


_NEGATIVE = re.compile(r"^-(\d|\.\d)")


def glue_negative_values(argv: list[str], value_options: set[str]) -> list[str]:
    """``--opt -0.8e-3,0.6e-3`` as ``--opt=-0.8e-3,0.6e-3``: argparse takes a value that
    starts with '-' for an option unless it is a plain negative number."""
    out: list[str] = []
    i = 0
    while i < len(argv):
        a = argv[i]
        if a in value_options and i + 1 < len(argv) and _NEGATIVE.match(argv[i + 1]):
            out.append(f"{a}={argv[i + 1]}")
            i += 2
            continue
        out.append(a)
        i += 1
    return out


# a Rust source location that zenoh appends to its errors: " at /root/.cargo/.../lib.rs:62."
_RUST_AT = re.compile(r"\s*at /\S+\.rs:\d+\.?")


def user_message(exc: BaseException, clamp: bool | None = None) -> str:
    """The one line a user sees for ``exc``: its text without internal source locations;
    the thrust table's "clamp option" named as ``--clamp`` when the command has it
    (``clamp`` True), left out when it has not (False)."""
    text = _RUST_AT.sub("", str(exc)).strip()
    if clamp is not None:
        text = text.replace("(use the clamp option to saturate)",
                            "(add --clamp to saturate)" if clamp else "")
    text = re.sub(r"\[?Single\(([^()]*)\)\]?", r"\1", text)  # a Rust enum's Debug form
    text = re.sub(r"\bKeyError: ('[^']*')", r"missing key \1", text)  # Python's exception names
    text = re.sub(r"\((ValueError|TypeError): ", "(", text)
    return text.replace("!)", ")").replace(" )", ")").strip()


def quiet_expected_warnings() -> None:
    """Numerical RuntimeWarnings (overflow, invalid value, division by zero) of the toolkit's
    own computations (numpy's and scipy's Python-level functions included) are expected on bad inputs, whose results the commands check and report
    in words (non-finite trajectory, implausible mass, ...): not shown, unless the user asked
    for warnings (python -W / PYTHONWARNINGS)."""
    import warnings

    if sys.warnoptions:
        return
    warnings.filterwarnings("ignore", message=r"(overflow|invalid value|divide by zero) encountered",
                            category=RuntimeWarning,
                            module=r"(estimator|calibration|bench|common|mocap_bridge|tpods|numpy|scipy)(\.|$)")


def short_library_warnings() -> None:
    """A library's warning (matplotlib's, say) reaches the user as ``tpods: warning:
    (library) message``, not as an absolute path into the installed package and a source
    line; the toolkit's own warnings keep Python's form."""
    import warnings

    shown = warnings.showwarning
    if getattr(shown, "_tpods_short", False):
        return  # installed already (main called again in one process)

    def show(message, category, filename, lineno, file=None, line=None):
        parts = str(filename).replace("\\", "/").split("/")
        if "site-packages" in parts or "dist-packages" in parts:
            lib = parts[parts.index("site-packages" if "site-packages" in parts
                                    else "dist-packages") + 1]
            print(f"tpods: warning: ({lib}) {message}", file=file or sys.stderr)
            return
        shown(message, category, filename, lineno, file, line)

    show._tpods_short = True  # type: ignore[attr-defined]
    warnings.showwarning = show


def main(argv: list[str] | None = None) -> int:
    quiet_expected_warnings()
    short_library_warnings()
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parser.parse_args(glue_negative_values(argv, _value_options(parser)))
    func = getattr(args, "func", None)
    if func is None:  # a group given without its sub-command
        args.parser.print_help(sys.stderr)
        return 2
    try:
        return int(func(args) or 0)
    except UserError as exc:
        print(f"tpods: error: {user_message(exc, clamp=hasattr(args, 'clamp'))}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("tpods: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 141


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
