"""The plant simulator as a motion-capture source (``tpods mocap bridge --source sim``):
poses of the estimator's simulator played on the host clock through the bridge's
playback. It lives on the application floor because it joins the bridge and the
estimator."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from common.constants import ARM_M, PAPER_IZZ_KGM2, PAPER_MASS_KG
from common.errors import UserError
from common.runfolder import read_run
from estimator.plant.inputs import phase_sine
from estimator.plant.model import PlantParams
from estimator.plant.sim import SimConfig, simulate
from mocap_bridge.sources.playback import Playback, frames_from_planar


class SimSource(Playback):
    """Poses of the plant simulator, played on the host clock.

    :meth:`from_run` re-simulates a simulated run folder (its commands, its truth from
    run.json and its measurement settings, same seed: the poses equal its poses.csv);
    with no folder, the nominal 120 s phase-sine run of the paper.
    """

    @classmethod
    def from_run(cls, run_dir: Path | None, rate_scale: float = 1.0, body: str = "tpods1",
                 seed: int | None = None) -> SimSource:
        if run_dir is None:
            cmd_t, duty = phase_sine(120.0, 50.0)
            res = simulate(cmd_t, duty, PlantParams(PAPER_MASS_KG, PAPER_IZZ_KGM2),
                           config=SimConfig(seed=0 if seed is None else seed))
            name = "sim:phase-sine"
        else:
            run = read_run(run_dir)
            truth = run.truth
            if not truth:
                raise UserError(f"{run_dir}: run.json holds no simulation truth; "
                                "use --source replay:{run_dir} to replay its poses")
            st = run.meta.get("settings", {})
            try:
                params = PlantParams(float(truth["mass_kg"]), float(truth["izz_kgm2"]),
                                     float(truth.get("arm_m", ARM_M)),
                                     *(float(truth.get(k, 0.0)) for k in ("ct", "cr", "kb", "ax", "ay")))
                cfg = SimConfig(pose_rate_hz=float(st.get("pose_rate_hz", 120.0)),
                                noise_pos_m=float(st.get("noise_pos_m", 0.01)),
                                noise_yaw_rad=float(st.get("noise_yaw_rad", math.radians(1.0))),
                                drop=float(st.get("drop", 0.0)),
                                seed=st.get("seed", 0) if seed is None else seed,
                                initial_state=tuple(truth.get("initial_state", (0.0,) * 6)),
                                clamp=bool(st.get("clamp", False)))
            except (KeyError, TypeError, ValueError) as exc:
                raise UserError(f"{run_dir / 'run.json'}: bad truth or settings ({exc})") from None
            if run.duty_pct is not None and run.thrust_n is None:
                res = simulate(run.cmd_t, run.duty_pct, params, config=cfg)
            else:
                t_cmd, thrust = run.thrust_profile()
                res = simulate(t_cmd, np.zeros((len(t_cmd), 4)), params, config=cfg, thrust_n=thrust)
            name = f"sim:{run_dir}"
        nominal = np.rint((res.pose_t - res.cmd_t[0]) * res.config.pose_rate_hz).astype(np.int64) + 1
        src = cls(name, frames_from_planar(body, res.pose_t, res.pose, nominal), rate_scale)
        src.result = res
        return src
