"""Live estimation of a structure (issue 18): the module command streams merged into the
structure's command, and live equal to batch on the recorded structure run
(runs/fixtures/structure-run: two modules on a truss, 30 s at 60 Hz)."""

from __future__ import annotations

import json
import math
import threading

import numpy as np
import pytest

from common.errors import UserError
from common.runfolder import read_run
from common.thrust_table import ThrustTable
from common.wire import encode_command, encode_pose
from estimator.estimate import FilterOptions, estimate_run
from estimator.live.merge import ModuleMerger
from estimator.live.revisions import latest_per_frame
from estimator.live.runtime import LiveConfig, LiveEstimator, LiveRecorder, run_live
from tests.support.net import wait_for
from tpods.fixtures import FIXTURES_ROOT

FIXTURE = FIXTURES_ROOT / "structure-run"
T0 = 1.763e9
NAMES = ("mass", "izz", "cx", "cy")
WINDOW_S = 10.0


# ----------------------------------------------------------------------- the merger

def test_a_row_is_emitted_when_every_module_has_sent_it():
    m = ModuleMerger(("a", "b"))
    assert m.push("a", 1.0, [10, 0, 0, 0]) == []  # b's value at 1.0 not known yet
    assert m.push("b", 1.0, [0, 20, 0, 0]) == [(1.0, (10, 0, 0, 0, 0, 20, 0, 0))]
    # a module that did not switch: its next message (a hold, or its next switch) tells
    assert m.push("a", 2.0, [30, 0, 0, 0]) == []
    assert m.push("b", 2.5, [0, 20, 0, 0], kind="hold") == [(2.0, (30, 0, 0, 0, 0, 20, 0, 0))]
    assert m.pending == 1 and m.stats.emitted == 2 and m.stats.incomplete == 0


def test_a_lagging_module_is_held_after_the_wait_and_corrected_when_it_arrives():
    m = ModuleMerger(("a", "b"), stale_s=0.25)
    m.push("a", 1.0, [10, 0, 0, 0], arrival=1.0)
    m.push("b", 1.0, [0, 20, 0, 0], arrival=1.0)
    assert m.push("a", 2.0, [50, 0, 0, 0], arrival=2.0) == []
    assert m.next_deadline() == pytest.approx(2.25)
    assert m.due(2.2) == []
    # b's stream lags: after the wait, 2.0 is emitted with b's last value held
    assert m.due(2.3) == [(2.0, (50, 0, 0, 0, 0, 20, 0, 0))]
    assert m.stats.incomplete == 1
    # b's commands of 1.5 and 1.8 arrive late: 1.5 and 1.8 are new stamps (complete at
    # once), and the emitted 2.0 they govern is corrected once, at the next due()
    out = m.push("b", 1.5, [0, 0, 40, 0], arrival=2.4)
    out += m.push("b", 1.8, [0, 0, 60, 0], arrival=2.4)
    assert out == [(1.5, (10, 0, 0, 0, 0, 0, 40, 0)), (1.8, (10, 0, 0, 0, 0, 0, 60, 0))]
    assert m.due(2.41) == [(2.0, (50, 0, 0, 0, 0, 0, 60, 0))]
    assert m.stats.reemitted == 1 and m.due(2.42) == []


def test_bad_commands_are_counted_and_skipped():
    m = ModuleMerger(("a", "b"))
    assert m.push("c", 1.0, [0, 0, 0, 0]) == []
    for duty in ([0, 0, 0], [0, 0, 0, math.nan], [0, 0, 0, 101], ["x", 0, 0, 0]):
        assert m.push("a", 1.0, duty) == []
    assert m.push("a", math.inf, [0, 0, 0, 0]) == []
    assert m.stats.other_module == 1 and m.stats.cmds_bad == 5 and m.pending == 0
    # the end of the run: when every module has announced it
    m.push("a", 3.0, [0, 0, 0, 0], kind="end")
    assert m.end_t is None
    assert m.push("b", 3.0, [0, 0, 0, 0], kind="end") == [(3.0, (0.0,) * 8)]
    assert m.end_t == 3.0
    # a stamp still waiting for a module at the end of the stream: flushed with holds
    m.push("a", 4.0, [5, 5, 5, 5])
    assert m.flush() == [(4.0, (5.0,) * 4 + (0.0,) * 4)] and m.stats.incomplete == 1


# ------------------------------------------------------------- live equals batch

@pytest.fixture(scope="module")
def recorded():
    return read_run(FIXTURE)


def _messages(run, *, module_delay_s=0.0):
    """The run as the player and the bridge send it: each command row as one message per
    module (same stamp), then the poses it governs. ``module_delay_s`` holds the second
    module's messages after the first back by that much (they arrive after poses they
    govern; the first is on time, else the poses before it are dropped as uncommanded)."""
    st = run.structure
    ct, d = run.cmd_t, run.duty_pct
    msgs = []
    ci = 0
    late = []
    for k, (t, p) in enumerate(zip(run.pose_t, run.pose, strict=True)):
        while late and late[0][0] <= t:
            msgs.append(late.pop(0)[1])
        while ci < len(ct) and ct[ci] <= t:
            for j, m in enumerate(st.modules):
                kind = "end" if ci == len(ct) - 1 else "set"
                msg = ("cmd", {"body": m.name, "t": T0 + ct[ci], "duty": list(d[ci, 4 * j:4 * j + 4]),
                               "kind": kind})
                if j == 1 and module_delay_s and ci:
                    late.append((ct[ci] + module_delay_s, msg))
                else:
                    msgs.append(msg)
            ci += 1
        msgs.append(("pose", {"body": st.name, "frame": k + 1, "t": T0 + t, "x": p[0], "y": p[1],
                              "yaw": p[2], "occluded": False}))
    msgs.extend(m for _, m in late)
    while ci < len(ct):
        for j, m in enumerate(st.modules):
            msgs.append(("cmd", {"body": m.name, "t": T0 + ct[ci],
                                 "duty": list(d[ci, 4 * j:4 * j + 4]),
                                 "kind": "end" if ci == len(ct) - 1 else "set"}))
        ci += 1
    return msgs


def _live(run, recorder=None, **kw):
    cfg = LiveConfig(method="ls-ekf", ls_window_s=WINDOW_S, publish_rate_hz=0, ls_in_process=False)
    est = LiveEstimator(ThrustTable.default(), cfg, run.structure.name, recorder=recorder,
                        structure=run.structure)
    published = []
    est.publish = published.append
    for kind, m in _messages(run, **kw):
        if kind == "cmd":
            est.command(m)
        else:
            est.pose(m, m["t"])
            est.process(m["t"] + 0.01)
    est.finish()
    return est, published


@pytest.fixture(scope="module")
def batch_ls_ekf():
    e = estimate_run(FIXTURE, method="ls-ekf", estimate=NAMES,
                     filter_options=FilterOptions(ls_window_s=WINDOW_S, process_noise={6: 1e-4}))
    return e.ext


def _assert_equal_to_batch(est, ext, sig_frac=1e-6):
    """Same data, same filter: every parameter equal to a millionth of its sigma, sigmas
    to 1e-6 relative."""
    assert ext.names == NAMES
    sd = np.sqrt(np.diag(ext.P))
    sl = np.sqrt(np.diag(est.P))
    for i, name in enumerate(NAMES, start=6):
        assert abs(est.z[i] - ext.x[-1, i]) < sig_frac * sd[i], (name, est.z[i], ext.x[-1, i], sd[i])
        assert sl[i] == pytest.approx(sd[i], rel=1e-6), name


def test_live_equals_batch_on_the_recorded_structure_run(recorded, batch_ls_ekf):
    est, published = _live(recorded)
    s = est.summary()
    assert s["phase"] == "ls-ekf" and not s["diverged"]
    assert s["structure"] == "truss" and s["modules"] == ["tpods1", "tpods2"]
    c = s["counters"]
    assert c["merge_emitted"] == len(recorded.cmd_t) and c["merge_incomplete"] == 0
    assert c["before_ls"] + c["updates"] == len(recorded.pose_t)
    _assert_equal_to_batch(est, batch_ls_ekf)
    # the estimate carries the centre of mass with its covariance; the truth (structure.toml)
    # within 3 sigma
    truth = json.loads((FIXTURE / "run.json").read_text())["truth"]
    assert abs(s["com_x_m"] - truth["cx"]) < 3 * s["com_x_sigma_m"]
    assert abs(s["com_y_m"] - truth["cy"]) < 3 * s["com_y_sigma_m"]
    assert abs(s["mass_kg"] - truth["mass_kg"]) < 3 * s["mass_sigma_kg"]
    assert abs(s["izz_kgm2"] - truth["izz_kgm2"]) < 3 * s["izz_sigma_kgm2"]
    cov = np.array(s["cov_com_m2"])
    assert cov.shape == (2, 2) and math.sqrt(cov[0, 0]) == pytest.approx(s["com_x_sigma_m"])
    assert s["izz_origin_kgm2"] == pytest.approx(
        s["izz_kgm2"] + s["mass_kg"] * (s["com_x_m"] ** 2 + s["com_y_m"] ** 2))
    # nothing is published before the LS window's fit; then the centre of mass with it
    assert published and all(p["phase"] in ("ls-ekf",) for p in published)
    assert all("com_x_m" in p for p in published)
    assert published[0]["t"] >= T0 + WINDOW_S


def test_a_lagging_module_rewinds_the_fit_to_the_same_estimate(recorded, batch_ls_ekf):
    """The second module's messages arrive 30 ms after their time (after poses they
    govern were filtered on arrival): the merger emits each row when the second
    module's part arrives, the catch-up and the live filter re-filter from before it, and
    the estimate is the on-time stream's."""
    est, _ = _live(recorded, module_delay_s=0.03)
    c = est.summary()["counters"]
    assert c["align_cmds_late"] == 0 and c["align_cmds_rewound"] > 100
    _assert_equal_to_batch(est, batch_ls_ekf, sig_frac=1e-5)


def test_module_commands_up_to_5_ms_late_revise_the_published_estimates(recorded):
    """Every pose is filtered as it arrives; the poses a late module command governs are
    re-run and their estimates published again (rev > 0); from the takeover of the LS start
    on, every pose's estimate of the highest revision is the on-time stream's."""
    def live(**kw):  # the window's fit and catch-up done before the next pose: deterministic
        cfg = LiveConfig(method="ls-ekf", ls_window_s=WINDOW_S, publish_rate_hz=0,
                         ls_in_process=False, catchup_budget_s=10.0)
        est = LiveEstimator(ThrustTable.default(), cfg, recorded.structure.name,
                            structure=recorded.structure)
        published: list[dict] = []
        est.publish = published.append
        for kind, m in _messages(recorded, **kw):
            if kind == "cmd":
                est.command(m)
                continue
            est.pose(m, m["t"])
            est.process(m["t"])
            if est.phase == "ls-running":
                est._ls_future.result()
        est.finish()
        return est, published

    late, pub_late = live(module_delay_s=0.005)
    ontime, pub_on = live()
    c = late.summary()["counters"]
    assert c["align_before_first_cmd"] == 0 and c["align_poses_out"] == len(recorded.pose_t)
    assert c["updates"] > len(recorded.pose_t) // 2  # the live filter from the window's end
    assert c["rewinds"] > 50 and c["revised_published"] > 50
    assert ontime.summary()["counters"]["revised_published"] == 0
    assert all(m["rev"] > 0 for m in pub_late if m["revised"])
    a, b = latest_per_frame(pub_late), latest_per_frame(pub_on)
    both = [f for f in b if f in a and b[f]["phase"] == a[f]["phase"] == "ls-ekf"]
    assert len(both) > len(recorded.pose_t) // 3
    for f in both:
        for k in ("mass_kg", "izz_kgm2", "com_x_m", "com_y_m"):
            assert a[f][k] == pytest.approx(b[f][k], rel=1e-9, abs=1e-12), (f, k)
    first: dict[int, dict] = {}
    for m in pub_late:
        first.setdefault(m["frame"], m)
    corrected = [f for f in both if first[f]["rev"] == 0 and a[f]["rev"] > 0
                 and abs(first[f]["mass_kg"] - b[f]["mass_kg"]) > 1e-9 * b[f]["mass_kg"]]
    assert len(corrected) > 20  # the first estimates were off; their revisions are not


def test_the_recorded_folder_is_a_structure_run_batch_reads(recorded, tmp_path):
    rec = LiveRecorder(tmp_path / "live", {"kind": "live-estimate"}, structure=recorded.structure)
    est, _ = _live(recorded, recorder=rec)
    rec.close("success", {"final": est.summary()})
    run = read_run(tmp_path / "live")
    assert run.structure is not None and run.structure.name == "truss"
    assert run.duty_pct.shape[1] == 8 and len(run.pose_t) == len(recorded.pose_t)
    np.testing.assert_allclose(run.pose, recorded.pose, atol=1e-11)
    header = (tmp_path / "live" / "estimates.csv").read_text().splitlines()[0]
    assert header.endswith("com_x_m,com_x_sigma_m,com_y_m,com_y_sigma_m")
    a = estimate_run(tmp_path / "live", method="ls", estimate=NAMES).to_dict()
    b = estimate_run(FIXTURE, method="ls", estimate=NAMES).to_dict()
    # the folder holds 12-digit values: the same fit to a thousandth of a sigma
    for k, sk in (("mass_kg", "mass_sigma_kg"), ("izz_kgm2", "izz_sigma_kgm2"),
                  ("com_x_m", "com_x_sigma_m"), ("com_y_m", "com_y_sigma_m")):
        assert abs(a[k] - b[k]) < 1e-3 * b[sk], k


def test_a_structure_is_estimated_with_ls_ekf_only(recorded):
    with pytest.raises(UserError, match="ls-ekf only"):
        LiveEstimator(ThrustTable.default(), LiveConfig(method="ekf"), "truss",
                      structure=recorded.structure)


# ------------------------------------------------------------------ over Zenoh

def test_live_over_zenoh_subscribes_to_every_module(zenoh_pair, recorded, batch_ls_ekf):
    """Commands on tpods/tpods1/cmd and tpods/tpods2/cmd, poses on tpods/mocap/truss/pose
    (loopback peers): run_live merges them and ends where batch does."""
    pub, sub, _ = zenoh_pair
    cfg = LiveConfig(method="ls-ekf", ls_window_s=WINDOW_S, publish_rate_hz=10, ls_in_process=False,
                     max_wait_s=0.002)
    est = LiveEstimator(ThrustTable.default(), cfg, "truss", structure=recorded.structure)
    estimates = []
    sub_est = pub.declare_subscriber("tpods/truss/estimate", lambda s: estimates.append(
        s.payload.to_bytes()))
    out = {}
    th = threading.Thread(target=lambda: out.update(res=run_live(sub, est, exit_on_end=True,
                                                                 end_grace_s=1.0)))
    th.start()
    import zenoh

    # BLOCK: the test publishes as fast as it can; a dropped message would test Zenoh
    pubs = {k: pub.declare_publisher(k, congestion_control=zenoh.CongestionControl.BLOCK) for k in
            ("tpods/tpods1/cmd", "tpods/tpods2/cmd", "tpods/mocap/truss/pose")}
    from tests.support.net import matching

    assert wait_for(lambda: all(matching(p) for p in pubs.values()), 10.0)
    seq = 0
    first = True
    for kind, m in _messages(recorded):
        if kind == "pose" and first:
            # the first row before any pose: a pose that overtook it on another key would be
            # dropped as uncommanded (its stamp is long past), and the data would differ
            assert wait_for(lambda: est.counters.cmds_rx == 2, 10.0)
            first = False
        seq += 1
        if kind == "cmd":
            pubs[f"tpods/{m['body']}/cmd"].put(encode_command(m["body"], seq, m["t"],
                                                              tuple(m["duty"]), m["kind"]))
        else:
            h = 0.5 * m["yaw"]
            pubs["tpods/mocap/truss/pose"].put(encode_pose(
                "truss", m["frame"], m["t"], m["t"],
                (m["x"], m["y"], 0.0, 0.0, 0.0, math.sin(h), math.cos(h), m["yaw"])))
    th.join(60)
    assert not th.is_alive()
    assert wait_for(lambda: len(estimates) > 0, 5.0)
    sub_est.undeclare()
    res = out["res"]
    assert res.status == "success", res
    c = res.summary["counters"]
    assert c["poses_rx"] == len(recorded.pose_t) and c["malformed"] == 0
    assert c["cmds_rx"] == 2 * len(recorded.cmd_t) and c["other_body"] == 0, c
    _assert_equal_to_batch(est, batch_ls_ekf)
    msgs = [json.loads(p) for p in estimates]
    assert msgs and all("com_x_m" in m and "cov_com_m2" in m for m in msgs)


# ------------------------------------------------- [body] known values and priors

def test_known_centre_of_mass_and_mass_prior_live_equal_batch(recorded, tmp_path):
    """[body] with the centre of mass known (fixed: only mass and Izz estimated) and a
    mass prior of 1.6 +/- 0.02 kg (the LS window's fit takes it): live ends where
    ``estimate batch --method ls-ekf`` ends on the same folder; a known mass is refused."""
    import shutil
    from dataclasses import replace

    from common.structure import Body

    body = Body(mass_kg=1.6, mass_sigma_kg=0.02, com_m=(0.03, 0.0))
    st = replace(recorded.structure, body=body)
    folder = tmp_path / "run"
    shutil.copytree(FIXTURE, folder)
    st.write(folder)
    run = read_run(folder)
    assert run.structure.body.known() == {"cx": 0.03, "cy": 0.0}
    ext = estimate_run(folder, method="ls-ekf", estimate=None,
                       filter_options=FilterOptions(ls_window_s=WINDOW_S, process_noise={6: 1e-4})).ext
    assert ext.names == ("mass", "izz")
    est, _ = _live(run)
    assert est._names == ("mass", "izz") and "prior" in est._ls_kwargs()
    sd = np.sqrt(np.diag(ext.P))
    for i in (6, 7):
        assert abs(est.z[i] - ext.x[-1, i]) < 1e-6 * sd[i]
        assert math.sqrt(est.P[i, i]) == pytest.approx(sd[i], rel=1e-6)
    s = est.summary()
    assert (s["com_x_m"], s["com_y_m"], s["com_x_sigma_m"]) == (0.03, 0.0, 0.0)
    # the prior tightens the mass: below both the prior's sigma and the data-only sigma
    free, _ = _live(recorded)
    assert s["mass_sigma_kg"] < min(0.02, free.summary()["mass_sigma_kg"])
    with pytest.raises(UserError, match="mass as known"):
        LiveEstimator(ThrustTable.default(), LiveConfig(method="ls-ekf"), "truss",
                      structure=replace(st, body=Body(mass_kg=1.6)))


def test_cli_refusals_are_one_line(tpods_exe, tmp_path):
    from tests.support.cli import run

    for args, match in (
            (("--structure", str(FIXTURE / "structure.toml"), "--method", "ekf"), "ls-ekf only"),
            (("--structure", str(tmp_path / "none.toml")), "structure file not found")):
        r = run(tpods_exe, "estimate", "live", *args, "--duration", "1", "--quiet")
        lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
        assert r.returncode == 2 and len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
        assert lines[0].startswith("tpods: error: ") and match in lines[0]


def test_the_modules_table_uncertainty_is_in_the_live_sigma(recorded):
    """Modules whose tables state a 1 % scale uncertainty: the live sigmas are the totals
    (noise + thrust, from the consider covariance of the whole run at its end) and agree
    with batch LS's total on the same run within 10 %; the centre of mass has its thrust
    part too."""
    from dataclasses import replace

    from common.thrust_table import ThrustTable as TT

    d = ThrustTable.default().to_dict()
    d["uncertainty"] = {"scale_rel": 0.01}
    table = TT.from_dict(d)
    st = recorded.structure.with_table(table)  # what `--thrust-table` does to the modules
    assert st.states_uncertainty
    est, _ = _live(replace(recorded, structure=st))
    s = est.summary()
    assert s["thrust_uncertainty"]["included"]
    b = estimate_run(FIXTURE, table, method="ls", estimate=NAMES).to_dict()
    assert b["mass_sigma_thrust_kg"] > b["mass_sigma_noise_kg"]  # the table dominates here
    # the filter's noise part is larger (process noise on m); the thrust part is the batch's
    assert s["mass_sigma_thrust_kg"] == pytest.approx(b["mass_sigma_thrust_kg"], rel=0.1)
    assert s["izz_sigma_thrust_kgm2"] == pytest.approx(b["izz_sigma_thrust_kgm2"], rel=0.1)
    assert 0 < s["com_x_sigma_thrust_m"] and s["com_x_sigma_m"] > s["com_x_sigma_noise_m"]
