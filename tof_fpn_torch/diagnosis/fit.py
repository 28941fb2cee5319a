"""Maximum-likelihood fitting of a :class:`~tof_fpn_torch.diagnosis.model.DiagnosisModel`.

The scalar parameters are fitted with L-BFGS (torch autograd through the simulator chain, the
noise law and the likelihood; frames pooled, the objective is the NLL per observation). Terms
estimated in closed form (``Term.closed_form``: the column / row delay profiles of
``fpn_pattern``) are updated between L-BFGS rounds (``Term.update_closed_form``).
"""

from __future__ import annotations

import math
from dataclasses import replace

import torch

from .. import constants as K
from .data import Observations
from .incidence import FOV_KEY, INCIDENCE_KEY, choose_incidence
from .likelihood import Context, n_observations, nll
from .model import DiagnosisModel
from .params import from_u, to_u
from .prediction import predict
from .readout import READOUT_KEYS, update_readout

__all__ = [
    "FIT_ITERS",
    "FIT_ROUNDS",
    "FIT_TOL",
    "INLIER_Z",
    "evaluate",
    "evaluate_halves",
    "fit",
    "hessian",
    "init_model",
    "misfits_grossly",
    "robust_start",
]

#: Iterations of L-BFGS per fit.
FIT_ITERS: int = 40
#: A fit stops when a further round (fresh Hessian, L-BFGS) gains less than this many nats, or
#: after ``FIT_ROUNDS`` rounds.
FIT_TOL: float = 0.5
FIT_ROUNDS: int = 4
#: Pixels whose temporal mean or spread is within this many sigma of a grossly misfitting model
#: give the robust starting values that every candidate term is also tried from.
INLIER_Z: float = 4.0


def init_model(obs: Observations, scene) -> DiagnosisModel:
    """The baseline with starting values from the data (amplitude scale, noise level)."""
    cam = obs.camera()
    values = {
        "photons.responsivity": 1.0,
        "camera.conversion_gain": 1.0,
        "camera.read_noise": 1.0,
        "readout_fpn.cos_2pi3": 0.0,
        "readout_fpn.sin_2pi3": 0.0,
        "readout_fpn.cos_pi": 0.0,
        "readout_fpn.sample_phase": 0.25 * math.pi,
        "camera.ambient_irradiance": float(obs.camera().ambient_irradiance),
    }
    dt = obs.times[1:] - obs.times[:-1]
    model = DiagnosisModel(cam, values, frame_interval=float(dt.mean()) if dt.numel() else 1.0)
    with torch.no_grad():
        p = predict(model, obs, scene=scene)
        ok = obs.known & (obs.n > 0) & (obs.m_a > 0)
        # the angle of incidence (an estimated reflectance, taken from the amplitude, holds it)
        values.update(choose_incidence(obs, p.a0, ok & (not obs.scene_estimated)))
        if values[INCIDENCE_KEY] != 0.0:
            p = predict(model, obs, scene=scene)
            obs.notes.append(
                "the scene's reflectance is taken as albedo: the baseline holds the angle of "
                "incidence (Lambert's law, normals from the scene's depth through a pinhole of "
                f"{values[FOV_KEY]:.0f} deg horizontal field of view)"
            )
        k = float((obs.m_a[ok] / p.a0[ok]).median())
        a0 = p.a0 * k
        off = p.offset * k
        # noise of one component of (2/N) X_1, from the depth: s = sigma_D A / k_d
        k_d = K.SPEED_OF_LIGHT_AIR / (4 * math.pi * float(cam.modulation_frequency))
        if obs.frames >= 2:
            sd = torch.sqrt(obs.m2_d / (obs.n - 1).clamp_min(1))
        else:
            sd = (obs.m_d - obs.scene_depth).abs() * K.MAD_TO_SIGMA
        snr_ok = ok & torch.isfinite(sd) & (a0 > a0[ok].median())
        s = float((sd[snr_ok] * a0[snr_ok] / k_d).median())
        s = max(s, 1e-3 * float(a0[ok].median()), 1e-6)
        v = s * s * cam.n_phases / 2.0
        b = float(off[ok].median())
        g = max(2.0 * b / max(v, 1e-12), 1e-6)
        values["photons.responsivity"] = k * g
        values["camera.conversion_gain"] = g
        values["camera.read_noise"] = g * math.sqrt(max(v / 2.0, 1e-12))
        model.fpn_scale = g * s
        model.impulsive_level = 1.0
    return model


def fit(
    model: DiagnosisModel,
    obs: Observations,
    ctx: Context,
    sel: str = "all",
    free: list | None = None,
    iters: int = FIT_ITERS,
    rounds: int = 2,
    hint: dict | None = None,
) -> tuple[DiagnosisModel, float]:
    """Fit ``model`` to the ``sel`` pixels (``all``, ``train``); ``free``: the keys to fit
    (default every scalar); ``hint``: Hessian entries of the same objective at a nearby model
    (:func:`hessian`), taken in the whitening instead of finite differences of those keys (a
    preconditioner only: the optimum does not depend on it). Returns the fitted copy and its NLL
    (nats)."""
    model = model.copy()
    specs = [s for s in model.specs() if free is None or s.key in free]
    n_obs = max(n_observations(obs, ctx, sel), 1.0)
    closed = [t for t in model.terms if t.closed_form]
    for outer in range(rounds if closed else 1):
        with torch.no_grad():
            for t in closed:
                model = t.update_closed_form(
                    model, obs, ctx, predict(model, obs, scene=ctx.scene), sel
                )
        if not specs:
            break
        # Newton-like rounds (fresh Hessian each) until the NLL moves by less than the tolerance;
        # the baseline's column read-out pattern is re-estimated before every round after the
        # first L-BFGS run (before it, the periodic pattern would go into the random one)
        last, tmat = math.inf, None
        for i in range(FIT_ROUNDS):
            if model.random_columns and (i > 0 or outer > 0 or READOUT_KEYS[0] in model.profiles):
                first = READOUT_KEYS[0] not in model.profiles
                model = _readout_step(model, obs, ctx, sel)
                if first and READOUT_KEYS[0] in model.profiles:
                    tmat = None  # the objective changed: a fresh Hessian (the old one can stall)
            model, val, tmat = _minimise(model, obs, ctx, sel, specs, n_obs, iters, tmat, hint)
            if last - val < FIT_TOL:
                break
            last = val
    with torch.no_grad():
        value = float(nll(model, obs, ctx, predict(model, obs, scene=ctx.scene), model.values, sel))
    return model, value


def _readout_step(model: DiagnosisModel, obs, ctx, sel: str) -> DiagnosisModel:
    """The baseline's column read-out pattern re-estimated (``readout.update_readout``), taken
    only as far as it lowers the NLL of the ``sel`` pixels: the full step, half of it, or none
    (the estimate is linearised; where the model is far off or bent by a clip it can overshoot)."""
    with torch.no_grad():
        p = predict(model, obs, scene=ctx.scene)
        new = update_readout(model, obs, ctx, p, sel)
        base = float(nll(model, obs, ctx, p, model.values, sel))
        best, best_val = model, base
        for share in (1.0, 0.5):
            cand = new if share == 1.0 else _blend(model, new, share)
            val = float(nll(cand, obs, ctx, predict(cand, obs, scene=ctx.scene), cand.values, sel))
            if val < best_val - 1e-6:
                best, best_val = cand, val
                break
    return best


def _blend(old: DiagnosisModel, new: DiagnosisModel, share: float) -> DiagnosisModel:
    """``new`` with its read-out profiles ``share`` of the way from ``old``'s (zero if none)."""
    out = new.copy()
    for key in READOUT_KEYS:
        prev = old.profiles.get(key)
        cur = new.profiles[key]
        out.profiles[key] = cur * share if prev is None else prev + share * (cur - prev)
    return out


def _objective(model, obs, ctx, sel, specs, n_obs):
    """``(objective, u0, values, keys, charges)``: the NLL per observation of the ``sel`` pixels
    as a function of the unconstrained values ``u`` of ``specs`` (None outside the physical
    range), its starting point and the map from ``u`` to the model's values."""
    keys = [s.key for s in specs]
    charges = [s.key for s in specs if s.charge]
    # a stated charge (not fitted) is stated in DN: it moves with the gain too
    charges += [s.key for t in model.terms for s in t.specs if s.key in model.fixed and s.charge]
    u0 = torch.tensor([to_u(s, model.values[s.key]) for s in specs], dtype=torch.float64)
    g0 = model.values["camera.conversion_gain"]

    def values(u):
        # charges (e-) move with the conversion gain, so that a step of the gain alone keeps the
        # amplitude, the FPN and the levels fixed in DN (decorrelated variables)
        v = dict(model.values)
        v.update({s.key: from_u(s, u[i]) for i, s in enumerate(specs)})
        if "camera.conversion_gain" in keys:
            ratio = v["camera.conversion_gain"] / g0
            for key in charges:
                v[key] = v[key] * ratio
        return v

    def objective(u):
        try:
            v = values(u)
            out = nll(model, obs, ctx, predict(model, obs, v, ctx.scene), v, sel) / n_obs
        except ValueError:  # a step left the physical range (e.g. NaN, a negative level)
            return None
        return out if bool(torch.isfinite(out)) else None

    return objective, u0, values, keys, charges


def hessian(model: DiagnosisModel, obs, ctx, sel: str = "all", free=None) -> dict | None:
    """The Hessian of :func:`fit`'s objective (NLL per observation of the ``sel`` pixels, in the
    unconstrained variables) at ``model`` for the keys ``free``: ``{"keys", "matrix"}``, a
    ``hint`` for fits of models near it (e.g. each candidate term added to ``model``: the block
    of the keys they share is taken from here, the term's rows are computed). None where the
    objective is undefined."""
    specs = [s for s in model.specs() if free is None or s.key in free]
    n_obs = max(n_observations(obs, ctx, sel), 1.0)
    objective, u0, _, keys, _ = _objective(model, obs, ctx, sel, specs, n_obs)
    _, hess = _hessian(objective, u0)
    return None if hess is None else {"keys": keys, "matrix": hess}


def _minimise(model, obs, ctx, sel, specs, n_obs, iters, tmat=None, hint=None):
    """L-BFGS in whitened variables: the Hessian of the NLL at the start (finite differences of
    the autograd gradient, eigenvalues made positive) maps a unit step to one standard error of
    every parameter combination, so the badly conditioned directions (read noise vs shot noise,
    amplitude vs conversion gain) converge in a few iterations. Returns the model, its NLL and
    the whitening matrix (passed back in, a second round reuses it). A whitening built from a
    ``hint`` under which L-BFGS makes no step is replaced by a fresh one and L-BFGS run again."""
    objective, u0, values, keys, charges = _objective(model, obs, ctx, sel, specs, n_obs)
    known = None
    if tmat is None:
        known = _known(hint, keys)
        f0, tmat = _whitening(objective, u0, known)
        if f0 is None:
            return model, math.inf, None
    else:
        with torch.no_grad():
            f0 = objective(u0)
        if f0 is None:
            return model, math.inf, tmat

    def descend(t: torch.Tensor):
        w = _lbfgs(objective, u0, t, iters)
        with torch.no_grad():
            return u0 + t @ w, objective(u0 + t @ w)

    u, final = descend(tmat)
    if known is not None and (final is None or float(f0) - float(final) < FIT_TOL / n_obs):
        # no step from the hint's whitening: the hint is the Hessian of a nearby model, and a
        # closed-form update (or a misfit the term takes up) can move the model far from it,
        # where it no longer preconditions (the fit stalled at its start); a fresh one
        f0, tmat = _whitening(objective, u0, None)
        if f0 is None:
            return model, math.inf, None
        u, final = descend(tmat)
    if final is None or float(final) > float(f0):
        return model, float(f0) * n_obs, tmat
    with torch.no_grad():
        v = values(u)
    out = model.copy()
    for k in keys + [c for c in charges if c not in keys]:
        val = float(v[k])
        if math.isfinite(val):
            out.values[k] = val
    return out, float(final) * n_obs, tmat


def _gradient(objective, u: torch.Tensor):
    """``(objective(u), its gradient)``; ``(None, None)`` where the objective is undefined."""
    u = u.detach().requires_grad_(True)
    out = objective(u)
    if out is None:
        return None, None
    (g,) = torch.autograd.grad(out, u)
    return out.detach(), g


def _known(hint: dict | None, keys: list) -> tuple | None:
    """``(indices, block)``: the entries of ``hint`` (:func:`hessian`) among ``keys``."""
    if hint is None:
        return None
    pos = {k: i for i, k in enumerate(hint["keys"])}
    idx = [i for i, k in enumerate(keys) if k in pos]
    if not idx:
        return None
    src = torch.tensor([pos[keys[i]] for i in idx])
    return idx, hint["matrix"][src][:, src]


def _hessian(objective, u0: torch.Tensor, known=None):
    """``(objective(u0), H)``: finite differences of the autograd gradient, the rows of the
    ``known`` indices' block taken from ``known = (indices, block)`` (their rows against the
    other keys from the computed rows, by symmetry); ``(None, None)`` where undefined."""
    n = u0.numel()
    f0, gr0 = _gradient(objective, u0)
    if f0 is None:
        return None, None
    hess = torch.zeros(n, n, dtype=torch.float64)
    have = set(known[0]) if known is not None else set()
    step = 1e-4
    for i in range(n):
        if i in have:
            continue
        _, gi = _gradient(objective, u0 + step * torch.eye(n, dtype=torch.float64)[i])
        ok = gi is not None and bool(torch.isfinite(gi).all())
        hess[i] = (gi - gr0) / step if ok else 0.0
    if known is not None:
        idx = torch.tensor(known[0])
        rest = [i for i in range(n) if i not in have]
        hess[idx.view(-1, 1), idx.view(1, -1)] = known[1]
        if rest:
            r = torch.tensor(rest)
            hess[idx.view(-1, 1), r.view(1, -1)] = hess[r.view(-1, 1), idx.view(1, -1)].T
    return f0, 0.5 * (hess + hess.T)


def _whitening(objective, u0: torch.Tensor, known=None):
    """``(objective(u0), T)``: ``T`` maps a unit step to one standard error of every parameter
    combination (``V diag(1 / sqrt(|lambda|))`` of the Hessian, :func:`_hessian`);
    ``(None, None)`` where the objective is undefined at ``u0``."""
    f0, hess = _hessian(objective, u0, known)
    if f0 is None:
        return None, None
    n = u0.numel()
    # a parameter whose curvature is undefined here (a gradient that is infinite at ``u0``,
    # e.g. a square root at zero) is scaled by its spec alone: a unit step is one scale
    bad = ~torch.isfinite(torch.diagonal(hess))
    if not bool(torch.isfinite(hess).all()):
        hess = torch.where(bad.view(-1, 1) | bad.view(1, -1), torch.zeros_like(hess), hess)
        hess = torch.nan_to_num(hess, nan=0.0, posinf=0.0, neginf=0.0)
        hess = hess + torch.diag(bad.to(hess.dtype))
    try:
        lam, vec = torch.linalg.eigh(hess)
    except torch.linalg.LinAlgError:  # too ill-conditioned for LAPACK: the diagonal alone
        lam, vec = torch.diagonal(hess).clone(), torch.eye(n, dtype=torch.float64)
    top = float(lam.abs().max()) if n else 1.0
    lam = lam.abs().clamp_min(max(top, 1e-30) * 1e-8)
    return f0, vec / torch.sqrt(lam).view(1, n)


def _lbfgs(objective, u0: torch.Tensor, tmat: torch.Tensor, iters: int) -> torch.Tensor:
    """The whitened step ``w`` (``u = u0 + T w``) that L-BFGS finds from ``w = 0``."""
    n = u0.numel()
    w = torch.zeros(n, dtype=torch.float64, requires_grad=True)
    opt = torch.optim.LBFGS(
        [w],
        lr=1.0,
        max_iter=max(iters, 1),
        history_size=20,
        tolerance_grad=1e-9,
        tolerance_change=1e-12,
        line_search_fn="strong_wolfe",
    )

    def closure():
        opt.zero_grad()
        out = objective(u0 + tmat @ w)
        if out is None:
            return torch.tensor(1e30, dtype=torch.float64)
        out.backward()
        if w.grad is not None and not bool(torch.isfinite(w.grad).all()):
            w.grad.zero_()
        return out

    try:
        opt.step(closure)
    except RuntimeError:
        pass
    return w.detach()


def robust_start(model: DiagnosisModel, obs: Observations, ctx: Context, base: DiagnosisModel):
    """Starting values of the core parameters that a gross misfit cannot drag away: the model is
    refitted (from ``model``'s robust starting values) on the pixels whose temporal mean and
    spread are within ``INLIER_Z`` sigma of the fitted ``base``, twice. Returns ``(values,
    model)``; ``(None, None)`` when fewer than 1 % of the depth pixels are outside (nothing to
    protect from: :func:`misfits_grossly`)."""
    ok = _inliers(base, obs, ctx)
    if not _gross(ok, ctx):
        return None, None
    cur = model
    for _ in range(2):
        sub = replace(ctx, mask_d=ctx.mask_d & ok, mask_a=ctx.mask_a & ok, _frames={})
        cur, _ = fit(cur, obs, sub)
        ok = _inliers(cur, obs, ctx)
    return cur.values, cur


def misfits_grossly(model: DiagnosisModel, obs: Observations, ctx: Context) -> bool:
    """Whether at least 1 % of the depth pixels have a temporal mean or spread more than
    ``INLIER_Z`` sigma from ``model``'s (the robust starting values are worth a try)."""
    return _gross(_inliers(model, obs, ctx), ctx)


def _gross(ok: torch.Tensor, ctx: Context) -> bool:
    return float((~ok & ctx.mask_d).sum()) >= 0.01 * float(ctx.mask_d.sum())


def _inliers(model: DiagnosisModel, obs: Observations, ctx: Context) -> torch.Tensor:
    from .locate import channels

    with torch.no_grad():
        ch = channels(obs, predict(model, obs, scene=ctx.scene), ctx)
    ok = torch.ones_like(ctx.mask_d)
    for z, _, mask in ch.values():
        ok &= ~mask | (z.abs() < INLIER_Z)
    return ok


def evaluate(model: DiagnosisModel, obs: Observations, ctx: Context, sel: str = "all") -> float:
    """NLL (nats) of the ``sel`` pixels with the model's current values."""
    with torch.no_grad():
        return float(nll(model, obs, ctx, predict(model, obs, scene=ctx.scene), model.values, sel))


def evaluate_halves(model: DiagnosisModel, obs: Observations, ctx: Context) -> tuple[float, float]:
    """``(evaluate(..., "train"), evaluate(..., "test"))`` from one prediction."""
    with torch.no_grad():
        p = predict(model, obs, scene=ctx.scene)
        return tuple(float(nll(model, obs, ctx, p, model.values, s)) for s in ("train", "test"))
