"""Name the missing physics: every catalogue term not yet in the model is added, fitted on the
fitting half of the pixels (a checkerboard of blocks) and scored on the held-out half.

``score`` = held-out log-likelihood gain (nats) over the current model fitted on the same half;
``delta_aic`` = ``2 k - 2 (gain on the fitting half)`` with ``k`` the added parameters (the
effective degrees of freedom for the closed-form profiles). A term is significant when its
held-out gain is at least ``MIN_GAIN`` nats and its AIC falls by at least ``MIN_DAIC``
(both thresholds set on null recordings, docs/diagnosis.md). Starting values come from each
term's ``initial_values`` (closed-form least squares on the current residuals over a small grid
of the non-linear parameters), so one L-BFGS run per term suffices.
"""

from __future__ import annotations

import math
from dataclasses import replace

import torch

from .catalogue import CATALOGUE, Term, implemented
from .fit import FIT_ITERS, evaluate, evaluate_halves, fit, hessian
from .model import CORE_SPECS, DiagnosisModel
from .prediction import predict
from .threads import map_threads

__all__ = [
    "CANDIDATE_ITERS",
    "CONTENDER_SHARE",
    "FORM_TOLERANCE",
    "MIN_DAIC",
    "MIN_GAIN",
    "RUN_OFF_FACTOR",
    "initial_values",
    "rank",
]

#: A candidate term is named when its held-out log-likelihood gain is at least this many nats ...
MIN_GAIN: float = 10.0
#: ... and it lowers the AIC on the fitting half by at least this much.
MIN_DAIC: float = 10.0
#: Iterations of L-BFGS when a candidate term is fitted on the fitting half.
CANDIDATE_ITERS: int = 20
#: Candidates whose held-out gain is within this share of the best are fitted on (up to
#: ``fit.FIT_ITERS`` per round) before the ranking is taken.
CONTENDER_SHARE: float = 0.25
#: A further effect is named only when its held-out gain is at least this share of the largest
#: named effect's: a named effect whose true form differs from every modelled one by a relative
#: error ``e`` in shape leaves a misfit of about ``e^2`` of its gain, which some other term can
#: take up; 0.1 allows ``e`` of about 30 % (set on development recordings, docs/diagnosis.md).
FORM_TOLERANCE: float = 0.1
#: The fitting half's refit of a grossly misfitting model has run off from the all-pixel fit
#: (whose fit is then a further start of every candidate) when a value of its noise law differs
#: from the all-pixel fit's by more than this factor.
RUN_OFF_FACTOR: float = 2.0
#: the noise law's values compared for :data:`RUN_OFF_FACTOR` (positive, log-scaled)
_NOISE_LAW = ("photons.responsivity", "camera.conversion_gain", "camera.read_noise")
#: the owners of the core values taken from the robust start
_CORE_OWNERS = ("photons", "camera", "readout_fpn")


def initial_values(name: str, model: DiagnosisModel, obs, ctx) -> list[dict]:
    """Candidate starting values of term ``name`` for ``model`` (``Term.initial_values`` on the
    model's current prediction)."""
    with torch.no_grad():
        p = predict(model, obs, scene=ctx.scene)
    return CATALOGUE[name].initial_values(model, obs, ctx, p)


def _try(model: DiagnosisModel, term: Term, init: list[dict], obs, ctx) -> DiagnosisModel | None:
    """The best of ``model`` with ``term`` at each starting value (NLL of the fitting half); a
    closed-form term is taken as it is."""
    best, best_val = None, math.inf
    for v in init:
        cand = model.with_effect(term, v)
        if term.closed_form:
            return cand
        try:
            val = evaluate(cand, obs, ctx, "train")
        except ValueError:  # a starting value outside the term's physical range
            continue
        if val < best_val:
            best, best_val = cand, val
    return best


def _starts(term: Term, base_train: DiagnosisModel, obs, ctx, start_values) -> list:
    """The models a candidate's fit starts from: the current model with the term at its best
    starting value and, with ``start_values``, the same from the robust core values."""
    init = initial_values(term.name, base_train, obs, ctx)
    if not init:
        return []
    starts = [_try(base_train, term, init, obs, ctx)]
    if start_values is not None and not term.closed_form:
        # a badly misfitting model drives the noise law and the FPN far off; the term may
        # need the robust starting values of the diagnosis (then all core values are free)
        alt = base_train.copy()
        alt.values.update(
            {
                k: start_values[k]
                for k in start_values
                if k in alt.values and k.split(".")[0] in _CORE_OWNERS
            }
        )
        # its starting values of the term from its own predictions (e.g. a level in e- of the
        # robust model, not of the misfitting one)
        alt_init = init
        if term.restarts_from_robust_values:
            alt_init = initial_values(term.name, alt, obs, ctx)
        # both starts are fitted: the robust one may start worse (its noise law is not bent
        # to the misfit yet) and end far better (a clip level found once the noise is right)
        starts.append(_try(alt, term, alt_init, obs, ctx))
    region = term.region(obs)
    if region is not None and _holds_the_outliers(region, base_train, obs, ctx):
        # the core fitted without the pixels the term acts on: a misfit there (mixed pixels
        # far from either surface) bends the noise law of the current model, which the term's
        # fit from it may not undo within its iterations
        sub = replace(ctx, mask_d=ctx.mask_d & ~region, mask_a=ctx.mask_a & ~region, _frames={})
        core, _ = fit(base_train, obs, sub, "train", iters=CANDIDATE_ITERS)
        starts.append(_try(core, term, initial_values(term.name, core, obs, ctx), obs, ctx))
    return [s for s in starts if s is not None]


def _holds_the_outliers(region, model, obs, ctx) -> bool:
    """Whether ``region`` holds the depth pixels beyond 5 sd of ``model`` at least twice as
    often as its share of the pixels (else the core fitted without it is not worth a fit)."""
    with torch.no_grad():
        p = predict(model, obs, scene=ctx.scene)
    z = (obs.m_d - p.mu_d).abs() / torch.sqrt(p.sd_d**2 / obs.n.clamp_min(1) + p.tau_d**2)
    far = (z > 5) & ctx.mask_d
    n_far, n = int(far.sum()), int(ctx.mask_d.sum())
    if n_far == 0 or n == 0:
        return False
    share = float((region & ctx.mask_d).sum()) / n
    return float((far & region).sum()) / n_far >= 2 * share


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
    nll_train, nll_test = evaluate_halves(base_train, obs, ctx)
    # the core block of the Hessian, once: every candidate starts near the current model, and
    # its whitening computes only the term's own rows
    hint = hessian(base_train, obs, ctx, "train", free=[s.key for s in CORE_SPECS])
    with torch.no_grad():
        p_cur = predict(base_train, obs, scene=ctx.scene)
    run_off = start_values is not None and _ran_off(model, base_train)

    def one(name: str) -> dict | None:
        term = CATALOGUE[name]
        starts = _starts(term, base_train, obs, ctx, start_values)
        if not starts:
            return None
        if run_off:
            # a grossly misfitting model's noise law is barely determined: the fitting half's
            # refit has run far from the all-pixel fit, which is a start too
            starts.append(_try(model, term, initial_values(name, model, obs, ctx), obs, ctx))
            starts = [s for s in starts if s is not None]
        # every core value is free: a current model that misfits has its noise law and FPN
        # bent to the misfit, and the term must be able to undo that
        free = [s.key for s in term.specs] + [s.key for s in CORE_SPECS]
        # the closed-form profiles of the model (e.g. a member's weights) are updated once
        # before the term's fit, twice (before and after) when the term is one: its profile
        # starts from the model without it; the contenders below are fitted to the end
        rounds = 2 if term.closed_form else 1
        fits = [
            fit(s, obs, ctx, "train", free=free, iters=CANDIDATE_ITERS, rounds=rounds, hint=hint)
            for s in starts
        ]
        cand = min(fits, key=lambda t: t[1])[0]
        share = term.signature_share(obs, ctx, p_cur)
        return _score(name, cand, base_train, nll_train, nll_test, obs, ctx, free, share)

    names = [
        n for n in implemented() if n not in base_train.effects and (only is None or n in only)
    ]
    # the slow terms (a relay grid, many clip levels) start first
    out = [r for r in map_threads(one, names, first=lambda n: CATALOGUE[n].slow) if r is not None]
    out.sort(key=_key)
    # the contenders close to the best are fitted on to convergence before the order is taken:
    # which term wins must not hang on the iteration budget (a clip level that starts far from
    # the optimum converges more slowly than an outlier rate)
    top = out[0]["score"] if out and out[0]["score"] is not None else None
    if top is not None and top >= MIN_GAIN:

        def on(r: dict) -> dict:
            if r["score"] is None or r["score"] < (1 - CONTENDER_SHARE) * top:
                return r
            cand, _ = fit(r["model"], obs, ctx, "train", free=r["free"], iters=FIT_ITERS, hint=hint)
            share = r.get("signature_share")
            return _score(
                r["name"], cand, base_train, nll_train, nll_test, obs, ctx, r["free"], share
            )

        out = map_threads(on, out)
    out.sort(key=_key)
    for r in out:
        r.pop("free")
    return out, base_train


def _ran_off(model: DiagnosisModel, half: DiagnosisModel) -> bool:
    """Whether a value of the noise law of ``half`` (the fitting half's refit) differs from the
    one of ``model`` (the all-pixel fit) by more than :data:`RUN_OFF_FACTOR`."""
    if model is half:
        return False
    for k in _NOISE_LAW:
        a, b = abs(model.values.get(k, 0.0)), abs(half.values.get(k, 0.0))
        if a == 0.0 or b == 0.0:
            if a != b:
                return True
        elif abs(math.log(a / b)) > math.log(RUN_OFF_FACTOR):
            return True
    return False


def _key(r: dict) -> float:
    return -(r["score"] if r["score"] is not None else -math.inf)


def _score(name, cand, base_train, nll_train, nll_test, obs, ctx, free, share=None) -> dict:
    """Held-out gain and AIC change of the fitted candidate ``cand`` (term ``name``); both gains
    scaled by ``share``, the share of the misfit with the term's signature (None: 1)."""
    c_train, c_test = evaluate_halves(cand, obs, ctx)
    k = cand.n_parameters() - base_train.n_parameters()
    # the gain is what the term itself brings: against the current model fitted on the same
    # half, and against the candidate with the term switched off (its other values kept)
    off = cand.copy()
    off.terms = [t for t in off.terms if t.name != name]
    off_train, off_test = evaluate_halves(off, obs, ctx)
    gain_train = min(nll_train, off_train) - c_train
    gain = min(nll_test, off_test) - c_test
    if share is not None:
        gain_train, gain = gain_train * share, gain * share
    daic = 2 * k - 2 * gain_train
    ok = math.isfinite(gain) and gain >= MIN_GAIN and daic <= -MIN_DAIC
    return {
        "name": name,
        "score": round(gain, 3) if math.isfinite(gain) else None,
        "delta_aic": round(daic, 3) if math.isfinite(daic) else None,
        "added_parameters": round(k, 2),
        "significant": ok,
        "signature_share": None if share is None else round(share, 4),
        "model": cand,
        "free": free,
    }
