"""Make docs/figures/view_example.png: what a Foxglove client of ``tpods view`` receives.

A 20 s phase-sine run is simulated (2.268 kg, Izz 3.78e-3 kg m^2, 120 Hz poses, 50 Hz
commands) and filtered with the lean EKF (estimates at 10 Hz, as ``tpods estimate live``
publishes them). Its poses, commands and estimates are put on Zenoh (two in-process peers on
loopback) at 5x real time, served by :class:`tpods.viewer.LiveView`, received by a Foxglove
WebSocket protocol client and plotted with matplotlib from what the client decoded: the same
data a Foxglove session shows with docs/foxglove/tpods_layout.json. Not a screenshot.

    python docs/foxglove/make_view_example.py [OUT.png]
"""

from __future__ import annotations

import json
import math
import struct
import sys
import threading
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from websockets.sync.client import connect  # noqa: E402

from common.wire import (  # noqa: E402
    cmd_key,
    encode_command,
    encode_estimate,
    encode_pose,
    estimate_key,
    pose_key,
)
from common.zenoh_net import loopback_endpoint, open_session  # noqa: E402
from estimator.filters.ekf import run_ekf  # noqa: E402
from estimator.plant.inputs import phase_sine  # noqa: E402
from estimator.plant.model import PlantParams  # noqa: E402
from estimator.plant.sim import SimConfig, simulate  # noqa: E402
from tpods.viewer import LiveView, topics_for  # noqa: E402

T0 = 1763770000.0
SPEED = 5.0
BODY = "tpods1"


def _wait(cond, timeout=10.0) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.01)
    return cond()


def stream():
    """(time, kind, key, payload) of the simulated live run, in time order."""
    truth = PlantParams(2.268, 3.78e-3)
    cmd_t, duty = phase_sine(20.0, 50.0)
    res = simulate(cmd_t, duty, truth, config=SimConfig(seed=3, drop=0.02))
    ekf = run_ekf(res.pose_t, res.pose, res.cmd_t, res.thrust_n)
    out = []
    for i, (t, (x, y, yaw)) in enumerate(zip(res.pose_t, res.pose, strict=True)):
        out.append((t, pose_key("tpods/mocap", BODY),
                    encode_pose(BODY, i, T0 + t, T0 + t + 0.003,
                                (x, y, 0.0, 0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2), yaw))))
        if i % 12 == 0 and i > 0:  # 10 Hz estimates
            m, izz = ekf.x[i, 6], ekf.x[i, 7]
            sm, si = ekf.sigma[i, 6], ekf.sigma[i, 7]
            out.append((t + 1e-6, estimate_key(BODY), encode_estimate({
                "schema": "tpods.estimate/1", "body": BODY, "seq": i, "t": T0 + t, "frame": i,
                "t_pub": T0 + t + 0.002, "method": "ekf", "phase": "ekf",
                "mass_kg": m, "mass_sigma_kg": sm, "izz_kgm2": izz, "izz_sigma_kgm2": si,
                "mass_sigma_noise_kg": sm, "mass_sigma_thrust_kg": 0.0,
                "izz_sigma_noise_kgm2": si, "izz_sigma_thrust_kgm2": 0.0,
                "n_updates": int(ekf.updated[:i + 1].sum()),
                "nis": None if not np.isfinite(ekf.nis[i]) else float(ekf.nis[i]),
                "diverged": False, "inconsistent": False})))
    for k, (t, d) in enumerate(zip(res.cmd_t, res.duty_pct, strict=True)):
        out.append((t - 1e-6, cmd_key(BODY), encode_command(BODY, k, T0 + t, d)))
    out.sort(key=lambda r: r[0])
    return out, truth


def main(out_png: str) -> None:
    items, truth = stream()
    ep = loopback_endpoint()
    pub = open_session(listen=[ep], no_multicast=True)
    sub = open_session(connect=[ep], no_multicast=True)
    assert _wait(lambda: len(pub.info.peers_zid()) > 0)
    msgs: dict[str, list[dict]] = {}
    with LiveView(sub, port=0, bodies=[BODY]) as view, \
            connect(f"ws://127.0.0.1:{view.port}", subprotocols=["foxglove.sdk.v1"]) as ws:
        channels: dict[str, int] = {}
        subs: dict[int, str] = {}

        def read() -> None:
            try:
                for m in ws:
                    if isinstance(m, str):
                        d = json.loads(m)
                        if d["op"] == "advertise":
                            channels.update({c["topic"]: c["id"] for c in d["channels"]})
                    elif m[0] == 1:
                        sid = struct.unpack_from("<I", m, 1)[0]
                        if subs[sid] != topics_for(BODY)["frame"]:
                            msgs.setdefault(subs[sid], []).append(json.loads(m[13:]))
            except Exception:
                pass

        th = threading.Thread(target=read, daemon=True)
        th.start()
        tp = topics_for(BODY)
        assert _wait(lambda: set(tp.values()) <= set(channels))
        subs.update({i + 1: t for i, t in enumerate(tp.values())})
        ws.send(json.dumps({"op": "subscribe", "subscriptions": [
            {"id": i, "channelId": channels[t]} for i, t in subs.items()]}))
        b = view.bodies[BODY]
        assert _wait(lambda: b.pose.has_sinks() and b.estimate.has_sinks() and b.duty.has_sinks())
        pubs = {k: pub.declare_publisher(k) for k in {k for _, k, _ in items}}
        time.sleep(0.3)
        start = time.monotonic()
        for t, key, payload in items:
            delay = t / SPEED - (time.monotonic() - start)
            if delay > 0:
                time.sleep(delay)
            pubs[key].put(payload)
        n_est = sum(1 for _, k, _ in items if k.endswith("/estimate"))
        assert _wait(lambda: len(msgs.get(tp["estimate"], [])) == n_est), view.counters
        time.sleep(0.3)
    sub.close()
    pub.close()

    est, duty, pose = msgs[tp["estimate"]], msgs[tp["duty"]], msgs[tp["pose"]]
    te = np.array([e["t"] for e in est]) - T0
    fig, ax = plt.subplots(3, 1, figsize=(8, 7.5), sharex=True)
    m = np.array([e["mass_kg"] for e in est])
    ax[0].fill_between(te, [e["mass_lo_kg"] for e in est], [e["mass_hi_kg"] for e in est],
                       color="#4e98e2", alpha=0.3, label="mass -/+ 1 sigma (mass_lo_kg, mass_hi_kg)")
    ax[0].plot(te, m, color="#1f5fa8", label="mass_kg")
    ax[0].axhline(truth.mass_kg, color="k", ls=":", lw=1, label=f"truth {truth.mass_kg} kg")
    ax[0].set_ylim(truth.mass_kg - 0.5, truth.mass_kg + 0.5)
    ax[0].set_ylabel("kg")
    ax[0].set_title(f"{tp['estimate']}: live EKF mass with its 1-sigma band")
    ax[0].legend(loc="upper right", fontsize=8)
    td = np.array([d["t"] for d in duty]) - T0
    for k in range(1, 5):
        ax[1].step(td, [d[f"d{k}"] for d in duty], where="post", lw=1, label=f"d{k}")
    ax[1].set_ylabel("%")
    ax[1].set_title(f"{tp['duty']}: valve duties")
    ax[1].legend(loc="upper right", fontsize=8, ncol=4)
    tpz = np.array([p["t"] for p in pose]) - T0
    ax[2].plot(tpz, [p["yaw_deg"] for p in pose], ".", ms=2, color="#f5774d")
    ax[2].set_ylabel("deg")
    ax[2].set_xlabel("lab time since the first pose, s")
    ax[2].set_title(f"{tp['pose']}: yaw_deg ({len(pose)} poses shown of 120 Hz, --pose-rate 50)")
    fig.suptitle("tpods view: the data a Foxglove client receives (matplotlib figure, not a "
                 "screenshot)", fontsize=10)
    fig.tight_layout()
    Path(out_png).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, dpi=110)
    print(f"wrote {out_png}: {len(est)} estimates, {len(duty)} commands, {len(pose)} poses "
          f"received; viewer counters {view.counters}")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "docs/figures/view_example.png")
