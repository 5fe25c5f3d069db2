"""The size checks of the long commands, from their option values before anything is
allocated: a simulation (``tpods sim``), a Cramér-Rao bound (``estimate crlb``), a
D-optimal design (``tpods design``) and a Monte Carlo (``estimate montecarlo``).

Each raises :class:`common.errors.UserError` when the work would take more than half the
available memory, its text naming the options that make it big (durations in s, rates
in Hz, as given), and announces on stderr work expected to take long
(:func:`common.sizes.announce`). The costs per sample are :mod:`common.sizes`'.
"""

from __future__ import annotations

from pathlib import Path

from common import sizes


def check_sim_size(duration_s: float, pose_rate_hz: float, cmd_rate_hz: float,
                   n_cmds: int | None = None, *, duration_given: bool = True,
                   input_name: str = "phase-sine") -> None:
    """A simulation of ``duration_s`` seconds of poses at ``pose_rate_hz``: command rows at
    ``cmd_rate_hz`` (a generated input) or ``n_cmds`` rows (a commands.csv
    ``input_name``; ``duration_given``: its span was cut by ``--duration``)."""
    n_poses = sizes.samples(duration_s, pose_rate_hz)
    cmds = sizes.samples(duration_s, cmd_rate_hz) if n_cmds is None else float(n_cmds)
    n_bytes, seconds = sizes.sim_cost(n_poses, cmds)
    span = (f"--duration {sizes.number(duration_s)} s" if n_cmds is None or duration_given
            else f"--input {input_name} ({sizes.number(duration_s)} s)")
    poses = (f"{span} at --pose-rate {sizes.number(pose_rate_hz)} Hz is "
             f"{sizes.samples_text(duration_s, pose_rate_hz)} poses")
    if n_cmds is None:
        what = (f"{span} at --pose-rate {sizes.number(pose_rate_hz)} Hz and --cmd-rate "
                f"{sizes.number(cmd_rate_hz)} Hz is {sizes.samples_text(duration_s, pose_rate_hz)} "
                f"poses and {sizes.samples_text(duration_s, cmd_rate_hz)} command rows")
        rate = ("--cmd-rate" if sizes.SIM_BYTES_PER_CMD * cmds > sizes.SIM_BYTES_PER_POSE * n_poses
                else "--pose-rate")
        fix = f"lower {rate} or --duration"
    else:
        what = poses
        fix = "lower --pose-rate or --duration" if duration_given else \
            "lower --pose-rate or give a shorter --duration"
    sizes.refuse_if_too_big(what, n_bytes, fix)
    sizes.announce(seconds, f"simulating {sizes.number(n_poses)} poses")


def check_planned_crlb_size(run_dir: str | Path, pose_rate_hz: float, n_params: int) -> None:
    """A bound over poses planned at ``pose_rate_hz`` over the span of the commands of
    ``run_dir`` (a folder or commands.csv without poses; a recorded run or a missing
    file: nothing to check here)."""
    from estimator.plant.inputs import from_commands_csv

    p = Path(run_dir)
    if p.is_dir() and (p / "poses.csv").exists():
        return  # a recorded run: its poses are read, checked by check_crlb_size
    csv = p / "commands.csv" if p.is_dir() else p
    if not csv.is_file():
        return  # load_sequence names what is missing
    cmd_t, _ = from_commands_csv(csv)
    span, n_cmds = float(cmd_t[-1] - cmd_t[0]), len(cmd_t)
    n_poses = sizes.samples(span, pose_rate_hz)
    segments = sizes.crlb_segments(n_poses, n_cmds, span)
    sizes.refuse_if_too_big(
        f"--pose-rate {sizes.number(pose_rate_hz)} Hz over the {sizes.number(span)} s of {csv} is "
        f"{sizes.samples_text(span, pose_rate_hz)} planned poses",
        sizes.crlb_cost(segments, n_params)[0], "lower --pose-rate")


def check_crlb_size(run_dir: str | Path, pose_t, n_cmds: int, n_params: int) -> None:
    """A bound over the poses at ``pose_t`` (s) with ``n_cmds`` command rows, of
    ``n_params`` parameters; announced when long."""
    span = float(pose_t[-1] - pose_t[0]) if len(pose_t) else 0.0
    n_poses = float(len(pose_t))
    n_bytes, seconds = sizes.crlb_cost(sizes.crlb_segments(n_poses, n_cmds, span), n_params)
    sizes.refuse_if_too_big(f"{run_dir} holds {n_poses:.0f} poses over {sizes.number(span)} s",
                            n_bytes, "restrict it with --window")
    sizes.announce(seconds, f"the bound over {n_poses:.0f} poses")


def check_design_size(duration_s: float, pose_rate_hz: float, cmd_rate_hz: float,
                      candidates: int, refine: int, refine_evals: int, n_compare: int) -> None:
    """A design of ``1 + candidates + refine * refine_evals + n_compare`` scored inputs:
    one candidate's bound and every candidate's trajectory, which the search keeps."""
    n_poses = sizes.samples(duration_s, pose_rate_hz)
    n_cmds = sizes.samples(duration_s, cmd_rate_hz)
    evals = 1 + candidates + refine * refine_evals + n_compare
    one_bytes, one_s = sizes.crlb_cost(sizes.crlb_segments(n_poses, n_cmds, duration_s), 2)
    kept = evals * sizes.DESIGN_KEPT_BYTES_PER_POSE * n_poses
    span = (f"--duration {sizes.number(duration_s)} s at --pose-rate "
            f"{sizes.number(pose_rate_hz)} Hz and --cmd-rate {sizes.number(cmd_rate_hz)} Hz")
    # one candidate (its bound and what the search keeps of it), then all of them
    sizes.refuse_if_too_big(
        f"{span} is {sizes.samples_text(duration_s, pose_rate_hz)} poses and "
        f"{sizes.samples_text(duration_s, cmd_rate_hz)} command rows per candidate",
        one_bytes + kept / evals, "lower --duration, --pose-rate or --cmd-rate")
    sizes.refuse_if_too_big(
        f"{evals} candidates (1 + --candidates {candidates} + --refine {refine} "
        f"x --refine-evals {refine_evals}"
        f"{f' + {n_compare} --compare' if n_compare else ''}) of "
        f"{sizes.samples_text(duration_s, pose_rate_hz)} poses each ({span})",
        one_bytes + kept, "lower --candidates, --refine-evals, --duration or --pose-rate")
    sizes.announce(evals * one_s, f"scoring {evals} candidates")


def check_montecarlo_size(duration_s: float, pose_rate_hz: float, cmd_rate_hz: float,
                          runs: int, structure: bool) -> None:
    """A Monte Carlo of ``runs`` runs of ``duration_s`` seconds (a structure's: one run
    simulated and fitted at a time)."""
    n_poses = sizes.samples(duration_s, pose_rate_hz)
    n_cmds = sizes.samples(duration_s, cmd_rate_hz)
    sizes.refuse_if_too_big(
        f"--duration {sizes.number(duration_s)} s at --pose-rate {sizes.number(pose_rate_hz)} "
        f"Hz and --cmd-rate {sizes.number(cmd_rate_hz)} Hz is "
        f"{sizes.samples_text(duration_s, pose_rate_hz)} poses and "
        f"{sizes.samples_text(duration_s, cmd_rate_hz)} command rows per run",
        sizes.montecarlo_bytes(n_poses, n_cmds, runs, structure),
        "lower --duration, --pose-rate or --cmd-rate")
