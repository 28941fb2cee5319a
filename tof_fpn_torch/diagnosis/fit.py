"""Maximum-likelihood fitting of a :class:`~tof_fpn_torch.diagnosis.model.DiagnosisModel`.

The scalar parameters are fitted with L-BFGS (torch autograd through the simulator chain, the
noise law and the likelihood; frames pooled, the objective is the NLL per observation). The
column / row delay profiles of ``fpn_pattern`` are fitted in closed form, alternating with
L-BFGS: for a column ``c`` the weighted mean ``m_c`` of the depth residuals (weights
``1 / var`` of the temporal means, residuals winsorised at 5 sigma) has variance
``sigma_c^2 + 1 / W_c`` around zero; ``sigma_c^2`` is estimated by moments and every column gets
its best linear unbiased prediction ``m_c sigma_c^2 / (sigma_c^2 + 1 / W_c)`` (the empirical
Bayes shrinkage of a random effect about zero), so that a column whose mean is noise is pulled to
zero; the profile keeps its mean (a delay common to all columns is a delay of the clock tree). The
shrinkage factors sum to the effective number of parameters counted by the AIC.
"""

from __future__ import annotations

import math

import torch

from .. import constants as K
from .data import Observations
from .likelihood import Context, n_observations, nll
from .model import DiagnosisModel, Prediction, predict
from .params import from_u, to_u

__all__ = ["evaluate", "fit", "init_model", "update_profiles"]

#: parameters in e- (they scale with the conversion gain while it is fitted)
_ELECTRONS = (
    "photons.responsivity",
    "camera.read_noise",
    "readout_fpn.cos_2pi3",
    "readout_fpn.sin_2pi3",
    "readout_fpn.cos_pi",
    "saturation.level",
    "amplitude_bias.reference",
)


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


def update_profiles(
    model: DiagnosisModel, obs: Observations, ctx: Context, pred: Prediction, sel: str = "all"
) -> DiagnosisModel:
    """Closed-form (empirical Bayes) column and row delay profiles from the depth residuals."""
    h, w = obs.shape
    m = ctx.mask_d & ctx.select(sel)
    old_c = model.profiles.get("columns", torch.zeros(w, dtype=torch.float64))
    old_r = model.profiles.get("rows", torch.zeros(h, dtype=torch.float64))
    with torch.no_grad():
        var = pred.sd_d.detach() ** 2 / obs.n.clamp_min(1)
        r = obs.m_d - pred.mu_d.detach() + old_c.view(1, w) + old_r.view(h, 1)
        if pred.wrap is not None:
            r = r - pred.wrap * torch.round(r / pred.wrap)
        lim = 5.0 * torch.sqrt(var)
        r = torch.maximum(torch.minimum(r, lim), -lim)
        wt = torch.where(m, 1.0 / var, torch.zeros_like(var))
        col = torch.zeros(w, dtype=torch.float64)
        row = torch.zeros(h, dtype=torch.float64)
        dof = 0.0
        rms = {}
        for _ in range(2):
            for axis, name in ((0, "columns"), (1, "rows")):
                other = row.view(h, 1) if axis == 0 else col.view(1, w)
                res = (r - other) * wt
                big_w = wt.sum(axis)
                has = big_w > 0
                mean = torch.where(has, res.sum(axis) / big_w.clamp_min(1e-300), 0.0)
                noise = torch.where(has, 1.0 / big_w.clamp_min(1e-300), 0.0)
                s2 = max(float(((mean**2 - noise)[has]).mean()), 0.0) if bool(has.any()) else 0.0
                shrink = torch.where(has, s2 / (s2 + noise), 0.0)
                prof = mean * shrink
                if axis == 0:
                    col = prof
                else:
                    row = prof
                rms[name] = math.sqrt(s2)
                if _ == 1:
                    dof += float(shrink.sum()) + 1.0
    out = model.copy()
    out.profiles = {"columns": col, "rows": row}
    out.values["fpn_pattern.dof"] = dof
    out.values["fpn_pattern.rms_columns"] = rms["columns"]
    out.values["fpn_pattern.rms_rows"] = rms["rows"]
    return out


def fit(
    model: DiagnosisModel,
    obs: Observations,
    ctx: Context,
    sel: str = "all",
    free: list | None = None,
    iters: int = K.DIAG_FIT_ITERS,
    rounds: int = 2,
) -> tuple[DiagnosisModel, float]:
    """Fit ``model`` to the ``sel`` pixels (``all``, ``train``); ``free``: the keys to fit
    (default every scalar). Returns the fitted copy and its NLL (nats)."""
    model = model.copy()
    specs = [s for s in model.specs() if free is None or s.key in free]
    n_obs = max(n_observations(obs, ctx, sel), 1.0)
    profile = "fpn_pattern" in model.effects
    for _ in range(rounds if profile else 1):
        if profile:
            with torch.no_grad():
                model = update_profiles(model, obs, ctx, predict(model, obs, scene=ctx.scene), sel)
        if not specs:
            break
        # Newton-like rounds (fresh Hessian each) until the NLL moves by less than the tolerance
        last, tmat = math.inf, None
        for _ in range(K.DIAG_FIT_ROUNDS):
            model, val, tmat = _minimise(model, obs, ctx, sel, specs, n_obs, iters, tmat)
            if last - val < K.DIAG_FIT_TOL:
                break
            last = val
    with torch.no_grad():
        value = float(nll(model, obs, ctx, predict(model, obs, scene=ctx.scene), model.values, sel))
    return model, value


def _minimise(model, obs, ctx, sel, specs, n_obs, iters, tmat=None):
    """L-BFGS in whitened variables: the Hessian of the NLL at the start (finite differences of
    the autograd gradient, eigenvalues made positive) maps a unit step to one standard error of
    every parameter combination, so the badly conditioned directions (read noise vs shot noise,
    amplitude vs conversion gain) converge in a few iterations. Returns the model, its NLL and
    the whitening matrix (passed back in, a second round reuses it)."""
    keys = [s.key for s in specs]
    u0 = torch.tensor([to_u(s, model.values[s.key]) for s in specs], dtype=torch.float64)
    g0 = model.values["camera.conversion_gain"]

    def values(u):
        # charges (e-) move with the conversion gain, so that a step of the gain alone keeps the
        # amplitude, the FPN and the levels fixed in DN (decorrelated variables)
        v = dict(model.values)
        v.update({s.key: from_u(s, u[i]) for i, s in enumerate(specs)})
        if "camera.conversion_gain" in keys:
            ratio = v["camera.conversion_gain"] / g0
            for key in _ELECTRONS:
                if key in keys:
                    v[key] = v[key] * ratio
        return v

    def objective(u):
        try:
            v = values(u)
            out = nll(model, obs, ctx, predict(model, obs, v, ctx.scene), v, sel) / n_obs
        except ValueError:  # a step left the physical range (e.g. NaN, a negative level)
            return None
        return out if bool(torch.isfinite(out)) else None

    def grad(u):
        u = u.detach().requires_grad_(True)
        out = objective(u)
        if out is None:
            return None, None
        (g,) = torch.autograd.grad(out, u)
        return out.detach(), g

    n = len(keys)
    if tmat is None:
        f0, gr0 = grad(u0)
        if f0 is None:
            return model, math.inf, None
        hess = torch.zeros(n, n, dtype=torch.float64)
        step = 1e-4
        for i in range(n):
            _, gi = grad(u0 + step * torch.eye(n, dtype=torch.float64)[i])
            ok = gi is not None and bool(torch.isfinite(gi).all())
            hess[i] = (gi - gr0) / step if ok else 0.0
        hess = 0.5 * (hess + hess.T)
        lam, vec = torch.linalg.eigh(hess)
        top = float(lam.abs().max()) if n else 1.0
        lam = lam.abs().clamp_min(max(top, 1e-30) * 1e-8)
        tmat = vec / torch.sqrt(lam).view(1, n)
    else:
        with torch.no_grad():
            f0 = objective(u0)
        if f0 is None:
            return model, math.inf, tmat
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
    with torch.no_grad():
        u = u0 + tmat @ w.detach()
        final = objective(u)
        if final is None or float(final) > float(f0):
            return model, float(f0) * n_obs, tmat
        v = values(u)
    out = model.copy()
    for k in keys:
        val = float(v[k])
        if math.isfinite(val):
            out.values[k] = val
    return out, float(final) * n_obs, tmat


def robust_start(model: DiagnosisModel, obs: Observations, ctx: Context, base: DiagnosisModel):
    """Starting values of the core parameters that a gross misfit cannot drag away: the model is
    refitted (from ``model``'s robust starting values) on the pixels whose temporal mean and
    spread are within ``DIAG_INLIER_Z`` sigma of the fitted ``base``, twice. ``None`` when fewer
    than 1 % of the depth pixels are outside (nothing to protect from)."""
    from dataclasses import replace as _replace

    from .locate import channels

    def inliers(m):
        with torch.no_grad():
            ch = channels(obs, predict(m, obs, scene=ctx.scene), ctx)
        ok = torch.ones_like(ctx.mask_d)
        for z, _, mask in ch.values():
            ok &= ~mask | (z.abs() < K.DIAG_INLIER_Z)
        return ok

    ok = inliers(base)
    if float((~ok & ctx.mask_d).sum()) < 0.01 * float(ctx.mask_d.sum()):
        return None
    cur = model
    for _ in range(2):
        sub = _replace(ctx, mask_d=ctx.mask_d & ok, mask_a=ctx.mask_a & ok, _frames={})
        cur, _ = fit(cur, obs, sub)
        ok = inliers(cur)
    return cur.values


def evaluate(model: DiagnosisModel, obs: Observations, ctx: Context, sel: str = "all") -> float:
    """NLL (nats) of the ``sel`` pixels with the model's current values."""
    with torch.no_grad():
        return float(nll(model, obs, ctx, predict(model, obs, scene=ctx.scene), model.values, sel))
