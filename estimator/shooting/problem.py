"""The multiple-shooting problem: every segment integrated from its own initial state with
the shared parameters, all segments and all Jacobian perturbations in one array pass.

State of a segment ``(x, y, psi, u, v, r)`` of the centre of mass, as the plant's
(:mod:`estimator.plant.model`): lab-frame position and yaw, body-frame velocities. The
dynamics are the plant's (thrusters, rigid body in a rotating frame, viscous damping
``ct``/``cr``, the ball-transfer torque ``kb``, the table tilt ``ax``/``ay``, the centre of
mass ``cx``/``cy`` off the tracked origin); the thrusts per thruster are
:mod:`estimator.shooting.inputs`' channels with efficiencies, a supply drop, a constant
body-frame wrench and the
dead time.

Integration is classical RK4 on a grid holding every pose time with steps of at most
:data:`MAX_STEP_S`, the thrust of each step its exact average over the step. Segments are
padded to one length with empty steps, so each RK4 stage is one array operation over
(perturbations, segments).

The Jacobian is by forward differences (central for the dead time), all at once: one
perturbation moves state j of EVERY segment (the segments are independent, so that
column block is block-diagonal: the block-arrow pattern), one each shared parameter.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from estimator.shooting.inputs import ThrustChannels
from estimator.shooting.segments import SegmentPlan

MAX_STEP_S = 0.05
"""Longest RK4 step, s (each step's thrust is its exact average, so a switch inside a step
costs O(F/m h^2/8): 6 um for 0.45 N on 23 kg)."""

GLOBAL_NAMES = ("mass", "izz", "cx", "cy", "ct", "cr", "kb", "ax", "ay", "delay", "drop", "scale",
                "bias.fx", "bias.fy", "bias.mz")
"""``bias.*``: a constant body-frame force (N) and moment about the tracked origin (N m) that
no command explains (a stuck-open valve, a tether, a hose)."""
"""Shared parameters besides the per-thruster ``eff.<name>``."""

LOG_NAMES = ("mass", "izz")
"""Parameters the fit works on in log space (positive; a step is relative)."""

DEFAULTS = {"bias.fx": 0.0, "bias.fy": 0.0, "bias.mz": 0.0,
            "mass": 1.0, "izz": 0.01, "cx": 0.0, "cy": 0.0, "ct": 0.0, "cr": 0.0, "kb": 0.0,
            "ax": 0.0, "ay": 0.0, "delay": 0.0, "drop": 0.0, "scale": 1.0}

STATE_FD = np.array([1e-5, 1e-5, 1e-6, 1e-5, 1e-5, 1e-6])
"""Forward-difference steps of the segment states (m, rad, m/s, rad/s)."""

PARAM_FD = {"bias.fx": 1e-6, "bias.fy": 1e-6, "bias.mz": 1e-7, "mass": 1e-6, "izz": 1e-6, "cx": 1e-6, "cy": 1e-6, "ct": 1e-5, "cr": 1e-6,
            "kb": 1e-6, "ax": 1e-7, "ay": 1e-7, "delay": 1e-3, "drop": 1e-5, "scale": 1e-6}
"""Difference steps of the shared parameters (log for mass and Izz; central for delay)."""
EFF_FD = 1e-6


def default_value(name: str) -> float:
    if name.startswith("eff."):
        return 1.0
    return DEFAULTS[name]


class ShootingProblem:
    """Residuals and Jacobian of a run cut into segments (module doc).

    Args:
        pose_t: (N,) pose times, s; pose: (N, 3) tracked x, y (m), yaw (rad).
        plan: the segments (:func:`estimator.shooting.segments.plan_segments`).
        channels: the vehicle's thrust channels (:func:`estimator.shooting.inputs.vehicle_channels`).
        names: the estimated shared parameters.
        fixed: values of the others (defaults :data:`DEFAULTS`, efficiency 1).
        sigma: (3,) pose noise (m, m, rad) that weights the residuals.
    """

    def __init__(self, pose_t, pose, plan: SegmentPlan, channels: ThrustChannels,
                 names: Sequence[str], fixed: Mapping[str, float], sigma) -> None:
        self.pose_t = np.asarray(pose_t, float)
        self.pose = np.asarray(pose, float)
        self.plan = plan
        self.ch = channels
        self.names = tuple(names)
        self.fixed = dict(fixed)
        self.sigma = np.asarray(sigma, float)
        self.thrusters = channels.names
        self._cum = channels.cumulative()
        self._build_grid()
        self.islog = np.array([n in LOG_NAMES for n in self.names], dtype=bool)

    # ------------------------------------------------------------------ grid
    def _build_grid(self) -> None:
        """Uniform RK4 steps of at most :data:`MAX_STEP_S` over each segment; every pose lies
        in a step (``node``) at a fraction ``frac`` of it, where the state is the cubic
        Hermite interpolant of the step's ends (fourth order, as RK4: poses at 120 Hz cost no
        more steps than poses at 20 Hz)."""
        S = self.plan.n
        n_steps = []
        h_seg = []
        for a, b in self.plan.bounds:
            span = float(self.pose_t[b - 1] - self.pose_t[a])
            n = max(1, int(math.ceil(span / MAX_STEP_S - 1e-9)))
            n_steps.append(n)
            h_seg.append(span / n)
        kmax = max(n_steps)
        self.h = np.zeros((S, kmax))
        for s_, (n, h) in enumerate(zip(n_steps, h_seg, strict=True)):
            self.h[s_, :n] = h
        self.t0 = np.array([self.pose_t[a] for a, _ in self.plan.bounds])
        self.ta = self.t0[:, None] + np.arange(kmax)[None, :] * np.array(h_seg)[:, None]
        self.tb = self.ta + self.h
        # residual rows: the poses of every segment in order
        self.seg = np.concatenate([np.full(b - a, s_) for s_, (a, b) in enumerate(self.plan.bounds)])
        self.obs = np.concatenate([np.arange(a, b) for a, b in self.plan.bounds])
        hobs = np.array(h_seg)[self.seg]
        u = (self.pose_t[self.obs] - self.t0[self.seg]) / hobs
        self.node = np.clip(np.floor(u).astype(int), 0, np.array(n_steps)[self.seg] - 1)
        self.frac = np.clip(u - self.node, 0.0, 1.0)
        self.hobs = hobs
        self.row_start = np.concatenate([[0], np.cumsum([3 * (b - a) for a, b in self.plan.bounds])])

    @property
    def n_seg(self) -> int:
        return self.plan.n

    # ------------------------------------------------------------------ values
    def values(self, theta: np.ndarray) -> dict[str, np.ndarray]:
        """Parameter values (P,) each from ``theta`` (P, p) (log names exponentiated)."""
        theta = np.atleast_2d(theta)
        P = theta.shape[0]
        out = {n: np.full(P, float(self.fixed.get(n, default_value(n)))) for n in GLOBAL_NAMES}
        for tn in self.thrusters:
            k = f"eff.{tn}"
            out[k] = np.full(P, float(self.fixed.get(k, default_value(k))))
        for j, n in enumerate(self.names):
            out[n] = np.exp(theta[:, j]) if n in LOG_NAMES else theta[:, j]
        return out

    def _wrench(self, vals: Mapping[str, np.ndarray]) -> np.ndarray:
        """(P, S, K, 3) step-average body wrench about the tracked origin. The thrusts are
        linear in the efficiencies and the drop, so each channel's wrench is
        formed once per distinct dead time and mixed per perturbation."""
        delays = vals["delay"]
        P = len(delays)
        eff = np.stack([vals[f"eff.{t}"] for t in self.thrusters], 1) * vals["scale"][:, None]
        coef = np.stack([eff, -eff * vals["drop"][:, None]], 1)  # (P, 2, N)
        S, K = self.h.shape
        out = np.empty((P, S, K, 3))
        uniq, inv = np.unique(delays, return_inverse=True)
        for u, d in enumerate(uniq):
            avg = self.ch.step_average(self.ta, self.tb, float(d), self._cum)  # (S, K, 3, N)
            rows = np.nonzero(inv.ravel() == u)[0]
            # per channel c and thruster n: its wrench W[:, n]; mixed by each row's coefficients
            out[rows] = np.einsum("pcn,skcn,mn->pskm", coef[rows], avg, self.ch.wrench,
                                  optimize=True)
        bias = np.stack([vals["bias.fx"], vals["bias.fy"], vals["bias.mz"]], 1)  # (P, 3)
        if np.any(bias):
            out += bias[:, None, None, :] * (self.h > 0)[None, :, :, None]
        return out

    def simulate(self, s0: np.ndarray, theta: np.ndarray):
        """``(states (K + 1, 6, P, S), d0 (K, 6, P, S), d1 (K, 6, P, S))``: the states at every
        grid node from ``s0`` (P, S, 6), ``theta`` (P, p), and the derivative at each step's
        start and end under that step's thrust (for the Hermite interpolant). Component-major:
        each state component of all perturbations and segments is one contiguous array."""
        vals = self.values(theta)
        wk_all = np.ascontiguousarray(np.moveaxis(self._wrench(vals), 2, 0).transpose(0, 3, 1, 2))
        P = s0.shape[0]
        col = {k: v.reshape(P, 1) for k, v in vals.items()}
        im, ii = 1.0 / col["mass"], 1.0 / col["izz"]
        ct, cr, kb, ax, ay = col["ct"], col["cr"], col["kb"], col["ax"], col["ay"]
        cx, cy = col["cx"], col["cy"]
        use_kb = bool(np.any(kb != 0))
        use_ct, use_cr = bool(np.any(ct != 0)), bool(np.any(cr != 0))
        use_tilt = bool(np.any(ax != 0) or np.any(ay != 0))
        K = self.h.shape[1]
        out = np.empty((K + 1, 6, P, self.n_seg))
        d0 = np.empty((K, 6, P, self.n_seg))
        d1 = np.empty((K, 6, P, self.n_seg))
        s = np.ascontiguousarray(np.moveaxis(s0, 2, 0))
        out[0] = s

        def f(s, fx, fy, mz, d):
            psi, u, v, r = s[2], s[3], s[4], s[5]
            c, sn = np.cos(psi), np.sin(psi)
            d[0] = u * c - v * sn
            d[1] = u * sn + v * c
            d[2] = r
            au, av = fx * im + r * v, fy * im - r * u
            if use_ct:
                au -= ct * u * im
                av -= ct * v * im
            if use_tilt:
                au += ax * c + ay * sn
                av += ay * c - ax * sn
            d[3] = au
            d[4] = av
            m = mz - cr * r if use_cr else mz
            if use_kb:
                m = m + kb * np.hypot(u, v)
            d[5] = m * ii
            return d

        k1, k2, k3, k4 = (np.empty_like(s) for _ in range(4))
        for k in range(K):
            h = self.h[:, k]
            fx, fy = wk_all[k, 0], wk_all[k, 1]
            mz = wk_all[k, 2] - (cx * fy - cy * fx)
            f(s, fx, fy, mz, k1)
            f(s + 0.5 * h * k1, fx, fy, mz, k2)
            f(s + 0.5 * h * k2, fx, fy, mz, k3)
            f(s + h * k3, fx, fy, mz, k4)
            s = s + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
            out[k + 1] = s
            d0[k] = k1
            f(s, fx, fy, mz, d1[k])
        return out, d0, d1

    def poses_at_obs(self, s0: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """(P, n_obs, 3) the centre of mass's x, y, psi at every pose of every segment (the
        cubic Hermite interpolant within a step: position and its lab-frame rate)."""
        return self._hermite(s0, theta, 3)

    def states_at_obs(self, s0: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """(P, n_obs, 6) the states at every pose of every segment (Hermite within a step)."""
        return self._hermite(s0, theta, 6)

    def _hermite(self, s0, theta, m: int) -> np.ndarray:
        x, d0, d1 = self.simulate(s0, theta)
        j, seg = self.node, self.seg
        th = self.frac[:, None, None]
        h = self.hobs[:, None, None]
        th2, th3 = th * th, th * th * th
        # advanced indices on axes 0 and 3: (n_obs, m, P)
        out = ((2 * th3 - 3 * th2 + 1) * x[j, :m, :, seg] + (th3 - 2 * th2 + th) * h * d0[j, :m, :, seg]
               + (3 * th2 - 2 * th3) * x[j + 1, :m, :, seg] + (th3 - th2) * h * d1[j, :m, :, seg])
        return np.moveaxis(out, 2, 0)  # (P, n_obs, m)

    def residuals(self, s0: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """(P, R) weighted residuals (measured - predicted tracked pose) / sigma, rows in
        segment order, three per pose (x, y, yaw wrapped)."""
        s0 = np.asarray(s0, float)
        theta = np.atleast_2d(theta)
        if s0.ndim == 2:
            s0 = s0[None]
        st = self.poses_at_obs(s0, theta)  # (P, n_obs, 3)
        vals = self.values(theta)
        P = st.shape[0]
        cx, cy = vals["cx"].reshape(P, 1), vals["cy"].reshape(P, 1)
        c, sn = np.cos(st[..., 2]), np.sin(st[..., 2])
        pred_x = st[..., 0] - (c * cx - sn * cy)
        pred_y = st[..., 1] - (sn * cx + c * cy)
        meas = self.pose[self.obs]
        r = np.empty((P, len(self.obs), 3))
        r[..., 0] = (meas[:, 0] - pred_x) / self.sigma[0]
        r[..., 1] = (meas[:, 1] - pred_y) / self.sigma[1]
        r[..., 2] = (np.mod(meas[:, 2] - st[..., 2] + np.pi, 2 * np.pi) - np.pi) / self.sigma[2]
        return r.reshape(P, -1)

    def jacobian(self, s0: np.ndarray, theta: np.ndarray):
        """``(r (R,), Js (R, 6), Jg (R, p))``: the residuals at ``(s0 (S, 6), theta (p,))``,
        each row's derivative by its own segment's six states, and by the shared parameters."""
        p = len(self.names)
        S = self.n_seg
        s_b = np.repeat(s0[None], 1 + 6 + p + 1, axis=0)
        th_b = np.repeat(theta[None], 1 + 6 + p + 1, axis=0)
        for j in range(6):
            s_b[1 + j, :, j] += STATE_FD[j]
        steps = np.empty(p)
        for j, n in enumerate(self.names):
            steps[j] = PARAM_FD.get(n, EFF_FD)
            th_b[7 + j, j] += steps[j]
        jd = self.names.index("delay") if "delay" in self.names else None
        if jd is not None:
            th_b[7 + p, jd] -= steps[jd]  # the backward point of the dead time's central difference
        else:
            s_b, th_b = s_b[:-1], th_b[:-1]
        r = self.residuals(s_b, th_b)
        r0 = r[0]
        Js = ((r[1:7] - r0) / STATE_FD[:, None]).T  # (R, 6): each row's own segment
        Jg = ((r[7:7 + p] - r0) / steps[:, None]).T
        if jd is not None:
            Jg[:, jd] = (r[7 + jd] - r[7 + p]) / (2 * steps[jd])
        del S
        return r0, Js, Jg

    # ------------------------------------------------------------------ start
    def initial_states(self, cx: float = 0.0, cy: float = 0.0, window_s: float = 0.5) -> np.ndarray:
        """(S, 6) a start for every segment: its first pose (moved to the centre of mass)
        and the velocities at it of a quadratic through its first ``window_s`` of poses
        (at least five poses): a velocity from two noisy poses 8 ms apart is off by metres
        per second and turns the yaw a full circle wrong."""
        out = np.zeros((self.n_seg, 6))
        for s, (a, b) in enumerate(self.plan.bounds):
            t = self.pose_t[a:b] - self.pose_t[a]
            m = max(min(5, b - a), int(np.searchsorted(t, window_s, side="right")))
            t = t[:m]
            x, y = self.pose[a:a + m, 0], self.pose[a:a + m, 1]
            psi = np.unwrap(self.pose[a:a + m, 2])
            deg = 2 if m >= 5 else 1
            vx, vy, r = (np.polyfit(t, q, deg)[-2] for q in (x, y, psi))
            c, sn = math.cos(psi[0]), math.sin(psi[0])
            out[s] = [x[0] + c * cx - sn * cy, y[0] + sn * cx + c * cy, psi[0],
                      c * vx + sn * vy, -sn * vx + c * vy, r]
        return out
