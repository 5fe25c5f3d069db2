"""The one output policy: every command that writes with ``--out`` goes through here.

- **One rule for --out.** A path ending in ``.toml``, ``.json`` or ``.mcap``
  (:data:`FILE_SUFFIXES`) names that file; anything else a folder that receives the
  command's files. A command whose result is one main file (``estimate batch`` ->
  ``estimate.json``, ``bench fit`` -> ``thrust_table.toml``, ...) takes either through
  :func:`result_output`: given a file with its main file's suffix it writes just that file,
  given a folder the main file and the rest (residuals, plots) in it. A command that writes
  a folder refuses a file name (:func:`check_folder`). ``.mcap`` is written only where
  MCAP is (:func:`stream_file`: ``mocap record`` and ``estimate live`` record the Zenoh
  streams into it; ``export mcap`` through :class:`ResultFile`) and refused elsewhere
  (:data:`MCAP_WRITERS` names them in the refusal).
- **Checked at the start.** ``--out ''``, a path under a file, an existing file where a
  folder is wanted (or a folder where a file is wanted) and a parent that cannot be
  created are a :class:`~common.errors.UserError` naming the path, before any work.
- **Never replaced without --force.** A non-empty folder (or, for a file output, an
  existing file) is refused with one line naming what is there, unless ``force``.
- **Written atomically.** :class:`ResultFolder` writes into a temporary sibling folder
  (same parent, ``.NAME.tmp-PID``) and renames it into place at the end; with ``force`` the
  old folder is replaced only once the new one is complete. An interrupted command leaves
  the old folder intact and either no new folder or a complete one. :class:`ResultFile`
  does the same for one file (written beside, then renamed).
- **Streams cannot be atomic.** :func:`stream_folder` (recorders: characterize, run play,
  estimate live, mocap record, demo) refuses a non-empty folder unless ``force``, which
  empties it first.
- **No stale temporaries.** A command killed outright (SIGKILL, power loss) leaves its
  ``.NAME.tmp-PID`` (and, killed between the two renames of a ``--force`` replace,
  ``.NAME.old-PID``). The next command that writes ``NAME`` removes them when process
  ``PID`` no longer runs (a ``.NAME.old-PID`` whose ``NAME`` is gone is renamed back to
  ``NAME``: the old results return), saying so in one line on stderr each
  (:func:`clean_stale`); the temporaries of a process that still runs are left alone.

Usage::

    out = ResultFolder(args.out, force=args.force, command="tpods sim")  # at the start
    ...                                                  # the work
    with out.writing() as d:                             # d: the temporary sibling
        (d / "poses.csv").write_text(...)
    print(f"wrote {out.path}")

    out = result_output(args.out, "estimate.json", force=args.force,
                        command="tpods estimate batch")  # ResultFile, ResultFolder or None
    with out.writing_main() as (main, d):                # d: None for a file output
        main.write_text(...)
        if d is not None:
            (d / "residuals.csv").write_text(...)
    print(f"wrote {out.main}")
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import sys
from collections.abc import Iterator
from pathlib import Path

from common.errors import UserError

_SHOW = 4  # entries named in a refusal

FILE_SUFFIXES = (".toml", ".json", ".mcap")
"""An ``--out`` ending in one of these names a file; anything else a folder."""


def add_force(parser, what: str = "--out") -> None:
    """Add ``--force`` (replace what ``what`` already holds) to an argparse parser."""
    parser.add_argument("--force", action="store_true",
                        help=f"replace what {what} already holds (default: refuse)")


def _holdings(folder: Path) -> list[str]:
    try:
        return sorted(p.name for p in folder.iterdir())
    except OSError:
        return []


def _listing(names: list[str]) -> str:
    shown = ", ".join(names[:_SHOW])
    return shown + (f", ... ({len(names)} entries)" if len(names) > _SHOW else "")


def _check_parent(path: Path, option: str) -> None:
    """The nearest existing ancestor of ``path`` must be a writable folder."""
    p = path.parent
    while True:
        if p.exists() or p.is_symlink():
            if not p.is_dir():
                raise UserError(f"{option} {path}: {p} is a file, not a folder; choose another {option}")
            if not os.access(p, os.W_OK | os.X_OK):
                raise UserError(f"{option} {path}: cannot write in {p} (permission denied); "
                                f"choose another {option}")
            return
        if p == p.parent:
            raise UserError(f"{option} {path}: no existing folder above it; choose another {option}")
        p = p.parent


def _base(path: str | Path | None, option: str) -> Path:
    if path is None or str(path).strip() == "":
        raise UserError(f"{option} is empty; give a folder or file name")
    return Path(path)


def names_a_file(path: str | Path) -> bool:
    """Whether ``path`` names a file by the --out rule (it ends in :data:`FILE_SUFFIXES`)."""
    return Path(path).suffix.lower() in FILE_SUFFIXES


MCAP_WRITERS = "tpods mocap record, tpods estimate live and tpods export mcap"
"""The commands that write an ``--out X.mcap`` (named when another command refuses one)."""


def is_mcap(path: str | Path | None) -> bool:
    """Whether ``path`` names an MCAP file by the --out rule."""
    return path is not None and Path(path).suffix.lower() == ".mcap"


def _not_mcap(p: Path, option: str, command: str, instead: str) -> None:
    if is_mcap(p):
        raise UserError(f"{option} {p}: {command} does not write MCAP (only {MCAP_WRITERS} "
                        f"do); it writes {instead}")


def _folder_base(path: str | Path | None, option: str, command: str | None) -> Path:
    """``path`` for a command that writes a folder: a file name (the --out rule) is refused."""
    p = _base(path, option)
    if names_a_file(p):
        command = command or "this command"
        _not_mcap(p, option, command, "a folder; give a folder name")
        raise UserError(f"{option} {p} names a file; {command} writes a folder of files; "
                        f"give a folder name (without {p.suffix})")
    return p


def _pid_alive(pid: int) -> bool:
    """Whether process ``pid`` runs (this process counts; when unsure: yes)."""
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # PermissionError: it runs, as another user; anything else: unsure
        return True
    return True


def _remove(p: Path) -> None:
    if p.is_dir() and not p.is_symlink():
        shutil.rmtree(p)
    else:
        p.unlink()


def clean_stale(path: str | Path) -> list[Path]:
    """Remove the temporaries a killed command left beside ``path`` (see the module doc).

    Looks in ``path``'s parent for ``.NAME.tmp-PID`` (a folder, or ``.STEM.tmp-PID.SUFFIX``
    for a result file) and ``.NAME.old-PID`` whose process ``PID`` no longer runs. A stale
    ``.NAME.old-PID`` is removed when ``NAME`` exists (the replace had completed) and
    renamed back to ``NAME`` otherwise. One line on stderr per temporary; returns them."""
    path = Path(path)
    parent, name = path.parent, path.name
    if not name or not parent.is_dir():
        return []
    pats = [re.compile(rf"\.{re.escape(name)}\.(?P<kind>tmp|old)-(?P<pid>\d+)")]
    if path.suffix:
        pats.append(re.compile(rf"\.{re.escape(path.stem)}\.(?P<kind>tmp)-(?P<pid>\d+){re.escape(path.suffix)}"))
    found: list[tuple[str, int, Path]] = []
    try:
        for child in parent.iterdir():
            for pat in pats:
                m = pat.fullmatch(child.name)
                if m:
                    found.append((m["kind"], int(m["pid"]), child))
                    break
    except OSError:
        return []
    done = []
    for kind, pid, child in sorted(found, key=lambda f: f[0] != "old"):  # .old first
        if _pid_alive(pid):
            continue
        try:
            if kind == "old" and not (path.exists() or path.is_symlink()):
                os.replace(child, path)
                msg = f"restored {path} from {child.name}, left by process {pid} (no longer running) while it replaced {name}"
            else:
                _remove(child)
                msg = f"removed {child}, a temporary left by process {pid} (no longer running: killed?)"
        except OSError as exc:
            msg = f"cannot remove {child}, a temporary left by process {pid} ({exc.strerror}); remove it by hand"
        print(f"tpods: warning: {msg}", file=sys.stderr)
        done.append(child)
    return done


def check_folder(path: str | Path | None, *, force: bool, option: str = "--out",
                 command: str | None = None) -> Path:
    """Check that ``path`` may become a result folder (see the module doc); return it.
    ``command`` (``"tpods sim"``) names the command in the refusal of a file name."""
    p = _folder_base(path, option, command)
    if p.exists() and not p.is_dir():
        raise UserError(f"{option} {p} is a file, not a folder; choose another {option}")
    _check_parent(p, option)
    if p.is_dir():
        names = _holdings(p)
        if names and not force:
            raise UserError(f"{p} already holds {_listing(names)}; add --force to replace it "
                            f"or choose another {option}")
    return p


def check_file(path: str | Path | None, *, force: bool, option: str = "--out") -> Path:
    """Check that ``path`` may become a result file; return it."""
    p = _base(path, option)
    if p.is_dir():
        raise UserError(f"{option} {p} is a folder, not a file; choose another {option}")
    _check_parent(p, option)
    if p.exists() and not force:
        raise UserError(f"{p} already exists; add --force to replace it or choose another {option}")
    return p


def check_plain_folder(path: str | Path | None, option: str) -> Path | None:
    """Check that ``path`` (an option naming a folder that receives files beside others',
    such as ``--plot-dir``; None: not given) is a folder or can become one: not a file,
    not under a file, in a writable place. Before any work; returns the path."""
    if path is None:
        return None
    p = _base(path, option)
    if p.exists() and not p.is_dir():
        raise UserError(f"{option} {p} is a file, not a folder; choose another {option}")
    if p.is_dir():
        if not os.access(p, os.W_OK | os.X_OK):
            raise UserError(f"{option} {p}: cannot write in it (permission denied); "
                            f"choose another {option}")
    else:
        _check_parent(p, option)
    return p


def _make_parent(path: Path, option: str) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"{option} {path}: cannot create {path.parent} ({exc.strerror})") from None


class ResultFolder:
    """A folder of results, checked now and written atomically by :meth:`writing`.

    ``main``: the name of the command's main file in it (see :func:`result_output`);
    :attr:`main` is then its final path."""

    is_folder = True

    def __init__(self, path: str | Path | None, *, force: bool = False, option: str = "--out",
                 command: str | None = None, main: str | None = None) -> None:
        clean_stale(_folder_base(path, option, command))
        self.path = check_folder(path, force=force, option=option, command=command)
        self.force = force
        self.option = option
        self.command = command
        self.main_name = main
        self.main = None if main is None else self.path / main
        self._tmp: Path | None = None

    def final(self, p: str | Path) -> Path:
        """``p`` (a path inside the temporary folder) as it reads after the rename."""
        p = Path(p)
        if self._tmp is not None:
            with contextlib.suppress(ValueError):
                return self.path / p.relative_to(self._tmp)
        return p

    @contextlib.contextmanager
    def writing(self) -> Iterator[Path]:
        """Yield an empty temporary sibling folder; rename it into place if the block ends
        normally, remove it otherwise (the old folder, if any, is untouched)."""
        path = self.path
        # checked again: something may have appeared while the command worked
        check_folder(path, force=self.force, option=self.option, command=self.command)
        _make_parent(path, self.option)
        tmp = path.parent / f".{path.name}.tmp-{os.getpid()}"
        shutil.rmtree(tmp, ignore_errors=True)
        try:
            tmp.mkdir()
        except OSError as exc:
            raise UserError(f"{self.option} {path}: cannot create {tmp} ({exc.strerror})") from None
        self._tmp = tmp
        try:
            yield tmp
            _replace_folder(tmp, path)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        finally:
            self._tmp = None

    @contextlib.contextmanager
    def writing_main(self) -> Iterator[tuple[Path, Path | None]]:
        """:meth:`writing`, yielding ``(main file, folder)`` inside the temporary folder."""
        with self.writing() as d:
            yield d / (self.main_name or "result"), d


def _replace_folder(new: Path, path: Path) -> None:
    """Rename ``new`` to ``path``; an existing ``path`` is moved aside first and removed
    only after the rename succeeded."""
    old = None
    if path.is_dir():
        if not any(path.iterdir()):
            path.rmdir()
        else:
            old = path.parent / f".{path.name}.old-{os.getpid()}"
            shutil.rmtree(old, ignore_errors=True)
            os.replace(path, old)
    try:
        os.replace(new, path)
    except BaseException:
        if old is not None:
            os.replace(old, path)
        raise
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


class ResultFile:
    """One result file, checked now and written atomically by :meth:`writing`."""

    is_folder = False

    def __init__(self, path: str | Path | None, *, force: bool = False, option: str = "--out") -> None:
        clean_stale(_base(path, option))
        self.path = check_file(path, force=force, option=option)
        self.main = self.path
        self.force = force
        self.option = option
        self._tmp: Path | None = None

    def final(self, p: str | Path) -> Path:
        """``p`` (the temporary file) as it reads after the rename."""
        return self.path if self._tmp is not None and Path(p) == self._tmp else Path(p)

    @contextlib.contextmanager
    def writing_main(self) -> Iterator[tuple[Path, None]]:
        """:meth:`writing`, yielding ``(temporary file, None)``: a file output has no folder
        for the command's other files."""
        with self.writing() as tmp:
            yield tmp, None

    @contextlib.contextmanager
    def writing(self) -> Iterator[Path]:
        """Yield a temporary path beside the file (same suffix); rename it over the file if
        the block ends normally, remove it otherwise."""
        path = self.path
        check_file(path, force=self.force, option=self.option)
        _make_parent(path, self.option)
        tmp = path.with_name(f".{path.stem}.tmp-{os.getpid()}{path.suffix}")
        self._tmp = tmp
        try:
            yield tmp
            os.replace(tmp, path)
        except BaseException:
            with contextlib.suppress(OSError):
                tmp.unlink()
            raise
        finally:
            self._tmp = None


def stream_folder(path: str | Path | None, *, force: bool, option: str = "--out",
                  command: str | None = None) -> Path:
    """Prepare a folder a recorder writes into as it goes (it cannot be atomic): checked
    as :func:`check_folder`; with ``force`` a non-empty folder is emptied. Returns the path
    (created)."""
    clean_stale(_folder_base(path, option, command))
    p = check_folder(path, force=force, option=option, command=command)
    if p.is_dir() and force:
        for child in p.iterdir():
            if child.is_dir() and not child.is_symlink():
                shutil.rmtree(child)
            else:
                child.unlink()
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"{option} {p}: cannot create the folder ({exc.strerror})") from None
    return p


def stream_file(path: str | Path | None, *, force: bool, option: str = "--out") -> Path:
    """Prepare a file a recorder writes into as it goes (an MCAP recording; it cannot be
    atomic): checked as :func:`check_file`; with ``force`` an existing file is removed.
    Returns the path (its parent created)."""
    p = check_file(path, force=force, option=option)
    if force and (p.exists() or p.is_symlink()):
        try:
            p.unlink()
        except OSError as exc:
            raise UserError(f"{option} {p}: cannot replace it ({exc.strerror})") from None
    _make_parent(p, option)
    return p


def optional_folder(path: str | Path | None, *, force: bool, option: str = "--out",
                    command: str | None = None) -> ResultFolder | None:
    """:class:`ResultFolder` for an optional ``--out``: None when the option was not
    given (``--out ''`` is given, and refused)."""
    return None if path is None else ResultFolder(path, force=force, option=option, command=command)


def result_output(path: str | Path | None, main: str, *, force: bool, command: str,
                  option: str = "--out") -> ResultFile | ResultFolder | None:
    """The --out rule for a command whose result is one main file (``main``, e.g.
    ``estimate.json``) with, in a folder, other files beside it.

    None when the option was not given; a :class:`ResultFile` when ``path`` ends in
    ``main``'s suffix; a refusal for another file suffix (:data:`FILE_SUFFIXES`); else a :class:`ResultFolder` that receives ``main`` and the rest.
    Write through ``writing_main()`` on either; ``.main`` is the main file's final path."""
    if path is None:
        return None
    p = _base(path, option)
    want = Path(main).suffix
    if names_a_file(p):
        instead = f"{main}: give a {want} file or a folder"
        _not_mcap(p, option, command, instead)
        if p.suffix.lower() != want:
            raise UserError(f"{option} {p} names a {p.suffix} file; {command} writes {instead}")
        return ResultFile(p, force=force, option=option)
    return ResultFolder(p, force=force, option=option, command=command, main=main)


def not_an_input(out: ResultFolder | None, *inputs: str | Path | None, option: str = "--out") -> None:
    """Refuse (even with --force) an output folder that is, or holds, one of the inputs."""
    if out is None:
        return
    o = out.path.resolve()
    for i in inputs:
        if i is None:
            continue
        p = Path(i).resolve()
        if p == o or o in p.parents:
            raise UserError(f"{option} {out.path} would replace the input {i}; choose another {option}")
