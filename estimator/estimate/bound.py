"""The use case of ``tpods estimate crlb``: :func:`bound_sequence`, the Cramér-Rao bound
of a recorded run or a planned command sequence (:mod:`estimator.estimate.sequence`) with
a structure's [body] priors and the thrust table's consider part beside it; its result
:class:`Bound`."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from common.constants import PAPER_IZZ_KGM2, PAPER_MASS_KG
from common.errors import UserError
from estimator.batch.crlb import CRLBResult, crlb, crlb_from_fisher
from estimator.estimate.knowledge import body_knowledge
from estimator.estimate.options import BoundOptions, as_window, with_overrides
from estimator.estimate.sequence import CommandSequence
from estimator.plant.parameter_sets import DEFAULT_MODEL, MODELS, with_model


@dataclass
class Bound:
    """Result of :func:`bound_sequence`: the bound, the poses it covers and the plant."""

    kind: str
    crlb: CRLBResult
    pose_t: np.ndarray
    mass_kg: float
    izz_kgm2: float
    plant_source: str
    data: dict[str, Any]

    def to_dict(self) -> dict[str, Any]:
        """The JSON object of ``tpods estimate crlb --json``."""
        return dict(self.data)


def bound_sequence(seq: CommandSequence, options: BoundOptions | None = None, *,
                   path: str = "", **overrides: Any) -> Bound:
    """Cramér-Rao bound of the model's parameters (initial state marginalised): the use
    case of ``tpods estimate crlb``.

    The settings are ``options`` (a :class:`BoundOptions`, default every default) with
    ``overrides`` replacing its fields by name (``bound_sequence(seq, window="1:18")``); an
    unknown keyword raises TypeError. The plant is ``mass_kg``/``izz_kgm2`` when given, else
    the run's truth, else the paper's module; ``path`` is recorded in the result as given.
    A structure's bound is on ``estimate`` (default :data:`STRUCTURE_ESTIMATE` less its
    [body] known values, as :func:`body_knowledge`), its [body] priors' information added
    to the Fisher matrix.
    """
    o = with_overrides(options, BoundOptions, overrides, "bound_sequence")
    window, mass_kg, izz_kgm2, model = o.window, o.mass_kg, o.izz_kgm2, o.model
    sigma_pos_m, sigma_yaw_rad, estimate = o.sigma_pos_m, o.sigma_yaw_rad, o.estimate
    keep_sensitivities = o.keep_sensitivities
    if estimate is not None and seq.structure is None:
        raise UserError("--estimate: the bound of a single-module run follows --model")
    t0, t1 = as_window(window)
    s0 = seq.s0
    if seq.kind == "recorded":
        run = seq.run.window(t0, t1) if (t0, t1) != (None, None) else seq.run
        pose_t = run.pose_t
        if run.pose_t[0] != seq.run.pose_t[0]:
            s0 = [*run.pose[0], 0.0, 0.0, 0.0]
    else:
        pose_t = seq.pose_t
        keep = np.ones(len(pose_t), bool)
        if t0 is not None:
            keep &= pose_t >= t0
        if t1 is not None:
            keep &= pose_t <= t1
        if keep.sum() < 3:
            raise UserError(f"window {window} holds fewer than 3 planned poses")
        pose_t = pose_t[keep]
    truth = seq.truth or {}
    body = seq.structure.body if seq.structure is not None else None
    mass = mass_kg or truth.get("mass_kg") or (body and body.mass_kg) or PAPER_MASS_KG
    izz = izz_kgm2 or truth.get("izz_kgm2") or (body and body.izz_kgm2) or PAPER_IZZ_KGM2
    source = "command line" if (mass_kg or izz_kgm2) else ("run truth" if truth else
                                                           "structure [body]" if body and body.mass_kg
                                                           else "paper nominal")
    params = {"mass": float(mass), "izz": float(izz), "arm": float(truth.get("arm_m", 0.05)),
              **{k: float(truth.get(k, 0.0)) for k in ("ct", "cr", "kb", "ax", "ay")}}
    names = MODELS[model or DEFAULT_MODEL]
    if seq.structure is not None:
        com = (truth["cx"], truth["cy"]) if "cx" in truth else ((body and body.com_m) or (0.0, 0.0))
        params.update(cx=float(com[0]), cy=float(com[1]))
        knowledge = body_knowledge(seq.structure, estimate, {})
        names = knowledge.names
        if model not in (None, DEFAULT_MODEL):  # friction/tilt: the model's parameters too
            names, _ = with_model(model, names)
    model = model or DEFAULT_MODEL
    try:
        with np.errstate(all="ignore"):
            c = crlb(pose_t, seq.cmd_t, seq.thrust_n, params, s0=s0, sigma_pos_m=sigma_pos_m,
                     sigma_yaw_rad=sigma_yaw_rad, keep_sensitivities=keep_sensitivities,
                     names=names)
        if not np.all(np.isfinite(c.fisher)):
            raise np.linalg.LinAlgError
    except (np.linalg.LinAlgError, OverflowError, FloatingPointError, ValueError):
        raise UserError(f"the bound cannot be computed: the predicted motion of a {mass:g} kg, "
                        f"Izz {izz:g} kg m^2 body under these thrusts is not finite (check --mass "
                        "and --izz, and the thrust table's unit)") from None
    if seq.structure is not None and knowledge.priors:
        c = _with_prior_information(c, knowledge.priors)
    out: dict[str, Any] = {
        "sequence": seq.kind, "path": str(path), "n_poses": c.n_poses,
        "duration_s": float(pose_t[-1] - pose_t[0]), "mass_kg": mass, "izz_kgm2": izz,
        "plant_source": source,
        "crlb_mass_sigma_kg": c.mass_sigma_kg, "crlb_izz_sigma_kgm2": c.izz_sigma_kgm2,
        "crlb_mass_rel": c.mass_sigma_kg / mass, "crlb_izz_rel": c.izz_sigma_kgm2 / izz,
        "crlb_corr_mass_izz": _corr(c, "mass", "izz"),
        "logdet_info": c.logdet, "sigma_pos_m": sigma_pos_m, "sigma_yaw_rad": sigma_yaw_rad,
        "model": model, "estimated": list(c.names)}
    if seq.structure is not None:
        for k, n in (("crlb_mass_sigma_kg", "mass"), ("crlb_izz_sigma_kgm2", "izz"),
                     ("crlb_mass_rel", "mass"), ("crlb_izz_rel", "izz")):
            if n not in c.names:
                out[k] = 0.0  # known: fixed at its value
        out.update(knowledge.to_dict())
    for n, s in zip(c.names, c.sigma, strict=True):
        if n not in ("mass", "izz"):
            out[f"crlb_{n}_sigma"] = float(s)
    sd = np.where(c.sigma > 0, c.sigma, 1.0)
    out["crlb_correlation"] = (c.cov / np.outer(sd, sd)).tolist()
    out.update(_bound_budget(seq, c, pose_t, params, s0, sigma_pos_m, sigma_yaw_rad))
    return Bound(seq.kind, c, pose_t, mass, izz, source, out)


def _corr(c: CRLBResult, a: str, b: str) -> float | None:
    """The bound's correlation of ``a`` and ``b`` (None when either is not estimated)."""
    if a not in c.names or b not in c.names:
        return None
    i, j = c.names.index(a), c.names.index(b)
    return float(c.cov[i, j] / (c.sigma[i] * c.sigma[j]))


def _with_prior_information(c: CRLBResult, priors: Mapping[str, tuple[float, float]]
                            ) -> CRLBResult:
    """The bound with Gaussian priors ``name -> (mean, sigma)`` on its parameters: their
    information ``1/sigma^2`` added to the Fisher matrix (the Bayesian bound of a linear
    Gaussian problem)."""
    F = np.array(c.fisher, float)
    for j, n in enumerate(c.names):
        if n in priors:
            F[6 + j, 6 + j] += priors[n][1] ** -2
    M, cov, sig, logdet = crlb_from_fisher(F, c.names)
    return replace(c, fisher=F, marginal_info=M, cov=cov, sigma=sig, logdet=logdet)


def _bound_budget(seq: CommandSequence, c: CRLBResult, pose_t, params, s0, sigma_pos_m,
                  sigma_yaw_rad) -> dict[str, Any]:
    """The total uncertainty beside the noise bound: the thrust table's consider part at the
    bound's plant (``*_sigma_thrust``, ``*_sigma_total``; total = RSS of the two)."""
    out: dict[str, Any] = {"thrust_uncertainty": {"included": seq.thrust_sens is not None,
                                                  "note": seq.thrust_note}}
    if seq.thrust_sens is None:
        return out
    from estimator.batch.consider import bound_consider

    s0 = np.zeros(6) if s0 is None else np.asarray(s0, float)
    cons = bound_consider(pose_t, seq.cmd_t, seq.thrust_sens, params, s0, c.names,
                          sigma_pos_m=sigma_pos_m, sigma_yaw_rad=sigma_yaw_rad)
    st = np.sqrt(np.maximum(np.diag(cons.cov_thrust)[6:], 0.0))
    total = np.hypot(c.sigma, st)
    out["thrust_uncertainty"]["terms"] = list(cons.names)
    for j, n in enumerate(c.names):
        key = {"mass": "mass_sigma_{}_kg", "izz": "izz_sigma_{}_kgm2"}.get(n, n + "_sigma_{}")
        out[key.format("thrust")] = float(st[j])
        out[key.format("total")] = float(total[j])
    return out
