"""The emulated bench of ``tpods bench emulate``: a valve controller and an OHAUS Scout
weighing the thrust of one of its nozzles, checked and linked (:func:`emulated_bench`), and
what they did, as CSV logs (:func:`write_logs`: times in s, duties in %, the balance's
lines) and one summary line."""

from __future__ import annotations

from pathlib import Path

from bench.emulators.scout import EmulatedScout
from bench.emulators.valves import EmulatedValveController
from common.errors import UserError
from common.thrust_table import load_thrust_table


def emulated_bench(channels: int = 4, nozzle_under_test: int = 1, table: str | None = None, *,
                   load_g: float = 0.0, lag_s: float = 0.3, noise_g: float = 0.2,
                   drift_g_per_s: float = 0.003, unstable_prob: float = 0.03,
                   garbage_prob: float = 0.01, rate_hz: float = 10.0, seed: int | None = None,
                   continuous_print: bool = True) -> tuple[EmulatedValveController, EmulatedScout]:
    """A valve controller of ``channels`` valves and a balance that feels valve
    ``nozzle_under_test`` through the thrust ``table`` (a TOML; None: the paper's Table 2),
    with the balance's load (g), lag (s), noise (g), drift (g/s), flag probabilities and
    print rate (Hz)."""
    thrust = load_thrust_table(table)
    if channels < 1:
        raise UserError("--channels must be at least 1")
    if not 1 <= nozzle_under_test <= channels:
        raise UserError(f"--nozzle-under-test must be 1-{channels}")
    for name, p in (("unstable_prob", unstable_prob), ("garbage_prob", garbage_prob)):
        if p > 1:
            raise UserError(f"--{name.replace('_', '-')} must be a probability (0-1)")
    valves = EmulatedValveController(channels)
    scout = EmulatedScout(valves, thrust, nozzle_under_test, load_g=load_g, lag_s=lag_s,
                          noise_g=noise_g, drift_g_per_s=drift_g_per_s,
                          unstable_prob=unstable_prob, garbage_prob=garbage_prob,
                          print_rate_hz=rate_hz, seed=seed, continuous_print=continuous_print)
    return valves, scout


def write_logs(d: Path, valves: EmulatedValveController, scout: EmulatedScout) -> None:
    """``valves_log.csv`` (t_s, cause, d1..dN) and ``scale_sent.csv`` (t_s, kind, line) in ``d``."""
    with (d / "valves_log.csv").open("w") as fh:
        fh.write("t_s,cause," + ",".join(f"d{i + 1}" for i in range(valves.n_channels)) + "\n")
        for ch in valves.log:
            fh.write(f"{ch.t:.6f},{ch.cause}," + ",".join(f"{x:g}" for x in ch.duties) + "\n")
    with (d / "scale_sent.csv").open("w") as fh:
        fh.write("t_s,kind,line\n")
        for s in scout.sent:
            fh.write(f"{s.t:.6f},{s.kind},{s.data.strip()!r}\n")


def stopped_line(valves: EmulatedValveController, scout: EmulatedScout) -> str:
    """What the emulated bench did, in one line."""
    return (f"stopped: {len(valves.log) - 1} valve change(s), {valves.watchdog_trips} watchdog trip(s), "
            f"{sum(s.kind == 'weight' for s in scout.sent)} reading(s) sent")
