"""A body's mass from a balance, a file of readings or typed values: the use case behind
``tpods calibrate mass``, callable from a notebook.

:func:`weigh` takes exactly one source (an OHAUS balance's serial port or pyserial URL,
a text file of hand-written readings, or numbers in ``unit``) and returns the
:class:`calibration.mass.MassResult` (kg, with its GUM uncertainty and warnings);
:func:`mass_lines` is its text report. Nothing is printed; a user error raises
:class:`common.errors.UserError`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

from calibration.mass import (
    MassResult,
    mass_from_readings,
    parse_readings_text,
    take_readings,
    to_kg,
)
from common.errors import DeviceError, UserError


def capture_file(target: str | Path | None) -> Path | None:
    """``--capture FILE.jsonl`` or DIR (-> DIR/scale.serial.jsonl); an existing file is refused."""
    if target is None:
        return None
    p = Path(target)
    p = p if p.name.endswith(".jsonl") else p / "scale.serial.jsonl"
    if p.exists():
        raise UserError(f"--capture: {p} already exists; choose another file or folder")
    if p.parent.exists() and not p.parent.is_dir():
        raise UserError(f"--capture {target}: {p.parent} is not a folder")
    return p


def scale_readings(url: str, n: int, *, baudrate: int = 9600, bytesize: int = 8,
                   parity: str = "N", stopbits: int = 1, timeout: float = 5.0,
                   capture: str | Path | None = None,
                   progress: Callable[[int], object] | None = None) -> tuple[list[float], int]:
    """``n`` stable readings (kg) of the OHAUS balance at ``url`` and the count of unstable
    ones skipped; ``capture`` records the serial link's transcript."""
    try:
        from bench.ohaus.driver import NotALoadReading, OhausScout  # lazy: pyserial, optional
    except ImportError:
        raise UserError("--scale needs the OHAUS driver (bench/ohaus/driver.py), which is not installed; "
                        "use --readings-from FILE or --values") from None
    with OhausScout(url, baudrate=baudrate, bytesize=bytesize, parity=parity, stopbits=stopbits,
                    timeout=timeout, stable_timeout=timeout, capture=capture_file(capture)) as scale:
        def read():
            try:
                return scale.read(mode="SP")
            except NotALoadReading:
                raise
            except DeviceError:  # only lines that are not weight lines, twice: not a balance
                if scale.n_readings == 0 and scale.n_garbage >= 2:
                    ex = scale.garbage_examples[-1].decode("ascii", "replace").strip()
                    raise NotALoadReading(
                        f"the device at {url} (--scale) does not answer like an OHAUS "
                        f"balance: {scale.n_garbage} replies that are not weight lines, the last "
                        f"{ex!r} (is it the balance, at --baudrate {baudrate}, "
                        f"--bytesize {bytesize}, --parity {parity}?)") from None
                raise

        return take_readings(read, n, progress=progress, fatal=(NotALoadReading,))


def weigh(*, scale: str | None = None, readings_from: str | Path | None = None,
          values: Sequence[float] | None = None, readings: int = 10, accuracy_g: float = 2.5,
          resolution_g: float = 0.0, unit: str = "g", capture: str | Path | None = None,
          progress: Callable[[int], object] | None = None, **serial) -> MassResult:
    """Mean, standard deviation and combined standard uncertainty (kg) of the readings of
    one source: ``scale`` (``readings`` stable ones; ``serial``: baudrate, bytesize,
    parity, stopbits, timeout of :func:`scale_readings`), ``readings_from`` (a text file,
    '?' marks an unstable reading) or ``values`` (in ``unit``). ``accuracy_g``: the
    balance's stated +-accuracy, ``resolution_g``: its display resolution, in g."""
    to_kg(1.0, unit)  # validates --unit
    if capture and not scale:
        raise UserError("--capture records the balance's serial link: it needs --scale")
    if scale:
        got, skipped = scale_readings(scale, readings, capture=capture, progress=progress, **serial)
    elif readings_from:
        path = Path(readings_from)
        if not path.is_file():
            raise UserError(f"{path}: file not found")
        try:
            text = path.read_text()
        except UnicodeDecodeError:
            raise UserError(f"{path}: not a text file") from None
        got, skipped = parse_readings_text(text, unit, str(path))
    elif values is not None:
        got, skipped = [to_kg(v, unit) for v in values], 0
    else:
        raise UserError("give one source: --scale, --readings-from or --values")
    return mass_from_readings(got, accuracy_g * 1e-3, resolution_g * 1e-3, skipped=skipped,
                              unit=None if scale else unit)


def mass_lines(res: MassResult, accuracy_g: float) -> list[str]:
    """The text report of a mass: the value with its uncertainties, in kg and g."""
    skipped = res.skipped
    return [f"mass = {res.mass_kg:.6g} kg +- {res.u_combined_kg:.2g} kg (standard uncertainty, k=1; "
            f"expanded U = {res.expanded_kg:.2g} kg, k=2)",
            f"  {res.n_readings} stable readings, std {res.std_kg * 1e3:.3g} g"
            + (f", {skipped} unstable skipped" if skipped else ""),
            f"  Type A (repeatability s/sqrt(N)) {res.u_typeA_kg * 1e3:.3g} g; Type B (+-{accuracy_g:g}"
            f" g rectangular, a/sqrt(3)) {res.u_typeB_kg * 1e3:.3g} g"
            + (f"; resolution {res.u_resolution_kg * 1e3:.3g} g" if res.u_resolution_kg else "")]
