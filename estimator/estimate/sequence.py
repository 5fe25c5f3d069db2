"""What ``tpods estimate crlb`` bounds: a recorded run or a planned command sequence
(:class:`CommandSequence`, :func:`load_sequence`), with the thrust table's sensitivity of
its thrusts when the table states an uncertainty."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from common.errors import UserError
from common.layout_files import as_layout, folder_layout
from common.runfolder import Run, read_run
from common.thrust_table import ThrustTable
from estimator.plant.inputs import from_commands_csv
from estimator.plant.sim import pose_times


@dataclass
class CommandSequence:
    """A recorded run or a planned command sequence (:func:`load_sequence`)."""

    kind: str  # "recorded" or "planned"
    cmd_t: np.ndarray
    thrust_n: np.ndarray
    pose_t: np.ndarray
    s0: Any
    run: Run | None = None
    truth: dict | None = None
    thrust_sens: Any = None  # ThrustSensitivity of the rows when the table states uncertainty
    thrust_note: str = ""
    structure: Any = None  # common.structure.Structure of a structure sequence (virtual thrusts)


def _sequence_sensitivity(seq: CommandSequence, table: ThrustTable | None, duty, clamp: bool
                          ) -> CommandSequence:
    """Attach the table's thrust sensitivity (or say why there is none)."""
    from common.thrust_uncertainty import thrust_sensitivity
    from estimator.batch.consider import NO_UNCERTAINTY, THRUSTS_GIVEN

    table = table if table is not None else ThrustTable.default()
    if duty is None:
        seq.thrust_note = THRUSTS_GIVEN
    elif not table.states_uncertainty:
        seq.thrust_note = NO_UNCERTAINTY
    else:
        seq.thrust_sens = thrust_sensitivity(table, duty, clamp=clamp)
    return seq


def _structure_sensitivity(seq: CommandSequence, sens, thrusts_given: bool) -> CommandSequence:
    """Attach a structure's virtual thrust sensitivity (or say why there is none)."""
    from estimator.batch.consider import NO_UNCERTAINTY, THRUSTS_GIVEN

    if thrusts_given:
        seq.thrust_note = THRUSTS_GIVEN
    elif sens is None or sens.empty:
        seq.thrust_note = NO_UNCERTAINTY
    else:
        seq.thrust_sens = sens
    return seq


def load_sequence(path: str | Path, table: ThrustTable | None, clamp: bool = False,
                  pose_rate_hz: float = 120.0, structure: Any = None) -> CommandSequence:
    """A run folder (with poses.csv), or a folder or commands.csv holding only commands
    (poses then planned at ``pose_rate_hz``, the module starting at rest at the origin).

    ``structure`` (a :class:`common.structure.Structure` or its TOML file; a run folder's
    own structure.toml otherwise) makes it a structure sequence: virtual thrusts, 4N duty
    columns, ``table`` for the modules without their own."""
    p = Path(path)
    structure = as_layout(structure)
    if p.is_dir() and (p / "poses.csv").exists():
        run = read_run(p, structure=structure)
        cmd_t, thrust = run.thrust_profile(table, clamp=clamp)
        truth = run.truth
        s0 = truth.get("initial_state") if truth else None
        if s0 is None:
            s0 = [*run.pose[0], 0.0, 0.0, 0.0]
        seq = CommandSequence("recorded", cmd_t, thrust, run.pose_t, s0, run, truth,
                              structure=run.structure)
        if run.structure is not None:
            return _structure_sensitivity(seq, run.thrust_sensitivity(table, clamp=clamp),
                                          run.thrust_n is not None)
        return _sequence_sensitivity(seq, table, run.duty_pct if run.thrust_n is None else None, clamp)
    csv = p / "commands.csv" if p.is_dir() else p
    if not csv.exists():
        raise UserError(f"{p}: neither a run folder with poses.csv nor a commands.csv")
    if structure is None and p.is_dir():
        structure = as_layout(folder_layout(p))
    if structure is not None:
        cmd_t, duty = from_commands_csv(csv, structure.n_channels)
        if len(cmd_t) < 2:
            raise UserError(f"{csv}: need at least two command rows (the last one ends the sequence)")
        s = structure.with_table(table) if table is not None else structure
        try:
            prof_t, thrust = s.input_profile(cmd_t, duty, clamp=clamp)
            sens = s.input_sensitivity(cmd_t, duty, clamp=clamp)[1] if s.states_uncertainty else None
        except UserError as exc:
            raise UserError(f"{csv}: {exc}") from None
        seq = CommandSequence("planned", prof_t, thrust, pose_times(cmd_t[0], cmd_t[-1], pose_rate_hz),
                              np.zeros(6), structure=s)
        return _structure_sensitivity(seq, sens, False)
    cmd_t, duty = from_commands_csv(csv)
    if len(cmd_t) < 2:
        raise UserError(f"{csv}: need at least two command rows (the last one ends the sequence)")
    if table is None:
        table = ThrustTable.default()
    try:
        thrust = table.thrust_n(duty, clamp=clamp)
    except UserError as exc:
        raise UserError(f"{csv}: {exc}") from None
    return _sequence_sensitivity(
        CommandSequence("planned", cmd_t, thrust, pose_times(cmd_t[0], cmd_t[-1], pose_rate_hz),
                        np.zeros(6)), table, duty, clamp)
