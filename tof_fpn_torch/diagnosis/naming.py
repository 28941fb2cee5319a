"""Name the missing physics: every catalogue term not yet in the model is added, fitted on the
fitting half of the pixels (a checkerboard of blocks) and scored on the held-out half.

``score`` = held-out log-likelihood gain (nats) over the current model fitted on the same half;
``delta_aic`` = ``2 k - 2 (gain on the fitting half)`` with ``k`` the added parameters (the
effective degrees of freedom for the closed-form profiles). A term is significant when its
held-out gain is at least ``DIAG_MIN_GAIN`` nats and its AIC falls by at least ``DIAG_MIN_DAIC``
(both thresholds set on null recordings, docs/diagnosis.md). Starting values come from closed-form
least squares on the current residuals over a small grid of the non-linear parameters, so one
L-BFGS run per term suffices.
"""

from __future__ import annotations

import math

import torch

from .. import constants as K
from .catalogue import CATALOGUE, implemented
from .fit import evaluate, fit
from .model import CORE_SPECS, DiagnosisModel, peak_samples, predict
from .threads import map_threads

__all__ = ["initial_values", "rank"]


def _ls(x: torch.Tensor, y: torch.Tensor, w: torch.Tensor) -> float:
    den = float((w * x * x).sum())
    return float((w * x * y).sum()) / den if den > 0 else 0.0


def initial_values(name: str, model: DiagnosisModel, obs, ctx) -> list[dict]:
    """Candidate starting values of term ``name`` (a small grid, least squares where linear)."""
    with torch.no_grad():
        p = predict(model, obs, scene=ctx.scene)
    g = model.values["camera.conversion_gain"]
    md, ma = ctx.mask_d, ctx.mask_a
    rd = (obs.m_d - p.mu_d)[md]
    wd = (obs.n / p.sd_d**2)[md]
    sd_med = float(p.sd_d[md].median()) if bool(md.any()) else 1e-3
    if name == "cyclic_error":
        return [{f"cyclic_error.{a}{i}": 0.0 for i in (1, 2) for a in ("cos", "sin")}]
    if name == "amplitude_bias":
        a_e = (p.a0 * g)[md]
        out = []
        for q in (0.1, 0.5, 0.9):
            ref = float(torch.quantile(a_e, q))
            b = _ls(ref / (a_e + ref), rd, wd)
            out.append({"amplitude_bias.delay": b, "amplitude_bias.reference": ref})
        return out
    if name == "fpn_pattern":
        return [{}]
    if name == "vignetting":
        h, w = obs.shape
        yy = torch.arange(h, dtype=torch.float64).view(h, 1) - (h - 1) / 2
        xx = torch.arange(w, dtype=torch.float64).view(1, w) - (w - 1) / 2
        r2 = ((xx**2 + yy**2) / (((h - 1) / 2) ** 2 + ((w - 1) / 2) ** 2))[ma]
        ratio = (obs.m_a / p.mu_a)[ma] - 1.0
        a2 = min(max(_ls(r2 - r2.mean(), ratio - ratio.mean(), torch.ones_like(r2)), -0.8), 0.8)
        return [
            {
                "vignetting.quadratic": a2,
                "vignetting.quartic": 0.0,
                "vignetting.centre_x": 0.0,
                "vignetting.centre_y": 0.0,
            }
        ]
    if name == "temporal_drift":
        if obs.frames < 3:
            return []
        vd = obs.valid & md
        e = torch.where(vd, (obs.depth - p.mu_d), torch.zeros_like(obs.depth)).sum((1, 2))
        e = e / vd.sum((1, 2)).clamp_min(1)
        va = obs.valid & ma
        ea = torch.where(va, obs.amplitude / p.mu_a - 1, torch.zeros_like(obs.amplitude))
        ea = ea.sum((1, 2)) / va.sum((1, 2)).clamp_min(1)
        span = float(obs.times[-1] - obs.times[0]) or 1.0
        out = []
        for f in (0.1, 0.3, 1.0, 3.0):
            u = 1 - torch.exp(-obs.times / (f * span))
            uc, one = u - u.mean(), torch.ones_like(u)
            out.append(
                {
                    "temporal_drift.depth_step": _ls(uc, e - e.mean(), one),
                    "temporal_drift.amplitude_step": _ls(uc, ea - ea.mean(), one),
                    "temporal_drift.time_constant": f * span,
                }
            )
        return out
    if name == "noise_floor":
        return [{"noise_floor.sigma": f * sd_med} for f in (0.1, 0.5, 1.5)]
    if name == "pixel_gain":
        return [{"pixel_gain.rms": r} for r in (0.002, 0.01, 0.03)]
    if name == "impulsive_pixels":
        if obs.frames < 2 and obs.known.sum() < 100:
            return []
        return [{"impulsive_pixels.rate": r} for r in (1e-4, 1e-3, 1e-2)]
    if name == "saturation":
        # the clip must touch some samples at the start, or the level's gradient is zero: levels
        # at high quantiles of the largest predicted raw sample and of the largest sample that
        # the observed amplitude and depth imply (a clipped pixel reads a smaller amplitude)
        out = []
        for peaks in (
            peak_samples(model, p, p.mu_d, p.a0),
            peak_samples(model, p, obs.m_d, obs.m_a),
        ):
            pk = (peaks * g)[ma & torch.isfinite(peaks)]
            if pk.numel():
                out += [
                    {"saturation.level": float(torch.quantile(pk, q))}
                    for q in K.DIAG_SATURATION_QUANTILES
                ]
        return out
    if name == "multipath":
        # a weak second return X_m turns pixel p's phasor X_p by Im(X_m / X_p): the depth moves
        # by strength * x_p, linear in the strength for each extra path on a grid
        f = float(model.camera.modulation_frequency)
        k = 4 * math.pi * f / K.SPEED_OF_LIGHT_AIR
        rho = ctx.scene.reflectance[0, 0].to(torch.float64)
        phi = p.mu_d * k
        ok = torch.isfinite(phi) & torch.isfinite(p.a0)
        m = torch.complex(p.a0 * torch.cos(phi), p.a0 * torch.sin(phi))[ok].mean()
        ratio = (rho / rho.mean()) / torch.complex(p.a0 * torch.cos(phi), p.a0 * torch.sin(phi))
        out = []
        for share in K.DIAG_MULTIPATH_PATH_SHARES:
            d_x = share * 2 * math.pi / k
            x = torch.imag(ratio * m * complex(math.cos(k * d_x), math.sin(k * d_x))) / k
            b = _ls(x[md], rd, wd)
            if b > 0:
                out.append(
                    {
                        "multipath.strength": min(b, 0.5),
                        "multipath.extra_path": d_x,
                        "multipath.scene_relay": 0.0,
                    }
                )
        # the relay within the scene: its depth shift per unit efficiency (a small one, linear)
        # on a grid of fields of view and near-field lengths, least squares for the efficiency
        eps = K.DIAG_SCALE_CYCLIC * 0.1
        for fov in K.DIAG_MULTIPATH_FIELDS_OF_VIEW:
            for near in K.DIAG_MULTIPATH_NEAR_FIELDS:
                geo = {
                    "multipath.strength": 0.0,
                    "multipath.extra_path": 0.0,
                    "multipath.scene_relay": eps,
                    "multipath.field_of_view": fov,
                    "multipath.near_field": near,
                }
                with torch.no_grad():
                    pg = predict(model.with_effect("multipath", geo), obs, scene=ctx.scene)
                x = ((pg.mu_d - p.mu_d) / eps)[md]
                b = _ls(x, rd, wd)
                if b > 0 and math.isfinite(b):
                    out.append(dict(geo, **{"multipath.scene_relay": b}))
        return out
    if name == "flying_pixels":
        return [{"flying_pixels.sigma": s} for s in (0.25, 0.4, 0.6, 0.85, 1.2)]
    if name == "phase_wrapping":
        out = []
        if obs.frequency is not None:
            out.append({"phase_wrapping.range": K.SPEED_OF_LIGHT_AIR / (2 * obs.frequency)})
        gap = (p.mu_d - obs.m_d)[md]
        big = gap > 0.25 * float(obs.scene_depth[obs.known].max())
        if int(big.sum()) >= 3:
            out.append({"phase_wrapping.range": float(gap[big].median())})
        return out
    return []


def _try(model, name, init, obs, ctx, nll_base) -> tuple[DiagnosisModel, float]:
    best, best_val = None, math.inf
    for v in init:
        cand = model.with_effect(name, v)
        if name == "fpn_pattern":
            return cand, nll_base
        try:
            val = evaluate(cand, obs, ctx, "train")
        except ValueError:  # a starting value outside the term's physical range
            continue
        if val < best_val:
            best, best_val = cand, val
    return best, best_val


def rank(
    model: DiagnosisModel, obs, ctx, base_train=None, only=None, start_values=None
) -> tuple[list[dict], DiagnosisModel]:
    """Fit every implemented term not in ``model``; candidates best first (held-out gain).

    Returns the ranking (dicts with ``name``, ``score``, ``delta_aic``, ``significant``,
    ``model``: the term's fit on the fitting half) and the current model fitted on that half.
    ``only``: the names to try (default every implemented term not in the model);
    ``start_values``: robust starting values of the core parameters, tried as a second start."""
    if base_train is None:
        base_train, _ = fit(model, obs, ctx, "train")
    nll_train = evaluate(base_train, obs, ctx, "train")
    nll_test = evaluate(base_train, obs, ctx, "test")

    def one(name: str) -> dict | None:
        init = initial_values(name, base_train, obs, ctx)
        if not init:
            return None
        starts = [_try(base_train, name, init, obs, ctx, nll_train)[0]]
        # every core value is free: a current model that misfits has its noise law and FPN
        # bent to the misfit, and the term must be able to undo that
        free = [s.key for s in CATALOGUE[name].specs] + [s.key for s in CORE_SPECS]
        if start_values is not None and name != "fpn_pattern":
            # a badly misfitting model drives the noise law and the FPN far off; the term may
            # need the robust starting values of the diagnosis (then all core values are free)
            alt = base_train.copy()
            alt.values.update(
                {
                    k: start_values[k]
                    for k in start_values
                    if k in alt.values and k.split(".")[0] in ("photons", "camera", "readout_fpn")
                }
            )
            # its starting values of the term from its own predictions (a level in e- of the
            # robust model, not of the misfitting one)
            alt_init = initial_values(name, alt, obs, ctx) if name == "saturation" else init
            alt_start, _ = _try(alt, name, alt_init, obs, ctx, nll_train)
            # both starts are fitted: the robust one may start worse (its noise law is not bent
            # to the misfit yet) and end far better (a clip level found once the noise is right)
            if alt_start is not None:
                starts.append(alt_start)
        starts = [s for s in starts if s is not None]
        if not starts:
            return None
        fits = [fit(s, obs, ctx, "train", free=free, iters=K.DIAG_CANDIDATE_ITERS) for s in starts]
        cand = min(fits, key=lambda t: t[1])[0]
        return _score(name, cand, base_train, nll_train, nll_test, obs, ctx, free)

    names = [
        n for n in implemented() if n not in base_train.effects and (only is None or n in only)
    ]
    # the relay grid of multipath and the clip levels of saturation are the slowest to fit
    slow = ("multipath", "saturation")
    out = [r for r in map_threads(one, names, first=lambda n: n in slow) if r is not None]
    out.sort(key=_key)
    # the contenders close to the best are fitted on to convergence before the order is taken:
    # which term wins must not hang on the iteration budget (a clip level that starts far from
    # the optimum converges more slowly than an outlier rate)
    top = out[0]["score"] if out and out[0]["score"] is not None else None
    if top is not None and top >= K.DIAG_MIN_GAIN:

        def on(r: dict) -> dict:
            if r["score"] is None or r["score"] < (1 - K.DIAG_CONTENDER_SHARE) * top:
                return r
            cand, _ = fit(r["model"], obs, ctx, "train", free=r["free"], iters=K.DIAG_FIT_ITERS)
            return _score(r["name"], cand, base_train, nll_train, nll_test, obs, ctx, r["free"])

        out = map_threads(on, out)
    out.sort(key=_key)
    for r in out:
        r.pop("free")
    return out, base_train


def _key(r: dict) -> float:
    return -(r["score"] if r["score"] is not None else -math.inf)


def _score(name, cand, base_train, nll_train, nll_test, obs, ctx, free) -> dict:
    """Held-out gain and AIC change of the fitted candidate ``cand`` (term ``name``)."""
    c_train = evaluate(cand, obs, ctx, "train")
    c_test = evaluate(cand, obs, ctx, "test")
    k = cand.n_parameters() - base_train.n_parameters()
    # the gain is what the term itself brings: against the current model fitted on the same
    # half, and against the candidate with the term switched off (its other values kept)
    off = cand.copy()
    off.effects.remove(name)
    gain_train = min(nll_train, evaluate(off, obs, ctx, "train")) - c_train
    gain = min(nll_test, evaluate(off, obs, ctx, "test")) - c_test
    daic = 2 * k - 2 * gain_train
    ok = math.isfinite(gain) and gain >= K.DIAG_MIN_GAIN and daic <= -K.DIAG_MIN_DAIC
    return {
        "name": name,
        "score": round(gain, 3) if math.isfinite(gain) else None,
        "delta_aic": round(daic, 3) if math.isfinite(daic) else None,
        "added_parameters": round(k, 2),
        "significant": ok,
        "model": cand,
        "free": free,
    }
