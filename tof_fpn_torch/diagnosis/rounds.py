"""The forward rounds of :func:`~tof_fpn_torch.diagnosis.diagnose` after the first ranking:
the best significant candidate is named (or joins the effect it is a form of), the forms of the
named effects are ranked before new effects (one effect, one name), and a backward pass drops a
term a later one made redundant."""

from __future__ import annotations

import math

import torch

from .catalogue import CATALOGUE, implemented
from .fit import evaluate, fit, misfits_grossly
from .locate import locate, statistics
from .naming import FORM_TOLERANCE, MIN_DAIC, rank
from .prediction import predict
from .threads import map_threads

__all__ = ["RETRY_GAIN", "RETRY_MAX", "forward", "prune"]

#: After a term is added, the next round re-fits only the candidates whose held-out gain was at
#: least this many nats (at most ``RETRY_MAX`` of them, best first), and those whose located
#: statistics are still significant.
RETRY_GAIN: float = 1.0
RETRY_MAX: int = 6


def forward(base, base_train, ranking, obs, ctx, before, start_values, only, max_effects):
    """Forward rounds from the first ``ranking``: the best significant candidate is added and
    the model refitted, until none is significant or ``max_effects`` effects are named. Returns
    the model, the last fit on the fitting half, the effects named (report entries; ``terms``:
    the catalogue terms, the forms, that model each) and every round's ranking (without the
    fitted models).

    One effect, one name: after an effect is named, a round of the other forms (flexible
    members) of the named effects comes first; the best significant one joins its effect (no
    new name). The round of new effects that follows fits them against that refit of the named
    effects, and names one only when its held-out gain is significant, above the form
    tolerance and, where no form joined, above the forms' best gain (:func:`_one_name`)."""
    rankings, effects, deferred, bar = [], [], None, -math.inf
    current, train_model = base, base_train
    while len(effects) < max_effects and len(rankings) < 3 * max_effects:
        rankings.append([{k: v for k, v in r.items() if k != "model"} for r in ranking])
        best = next((r for r in ranking if r["significant"]), None)
        if best is None and not deferred:
            break
        if best is not None:
            current, train_model = _take(best, current, effects, obs, ctx)
            if len(effects) == max_effects:
                break
        if deferred is None:  # after a round of new effects: the forms of the named ones first
            again = _next_candidates(ranking, best["name"], current, obs, ctx, before, only)
            named = {e["name"] for e in effects}
            forms = [n for n in again if CATALOGUE[n].effect in named]
            deferred = [n for n in again if n not in forms]
            if not forms:
                candidates, deferred = deferred, None
            else:
                candidates = forms
        else:  # after the forms: the new effects, against the named effects as refitted (if
            # no form joined, a new effect must gain more than the best of them did)
            bar = -math.inf if best is not None else _best_score(ranking)
            candidates = [n for n in deferred if n not in current.effects]
            candidates += [n for n in _signalled(current, obs, ctx, before) if n not in candidates]
            candidates = [n for n in candidates if only is None or n in only]
            named = {e["name"] for e in effects}
            candidates = [n for n in candidates if CATALOGUE[n].effect not in named]
            deferred = None
        # the robust starting values while the model still misfits grossly (nothing to
        # protect from after: the second start of every candidate's fit would cost its time)
        robust = start_values if misfits_grossly(current, obs, ctx) else None
        ranking, train_model = rank(current, obs, ctx, only=candidates, start_values=robust)
        ranking = _one_name(ranking, effects, bar)
        bar = -math.inf
    return current, train_model, effects, rankings


def _take(best: dict, current, effects: list, obs, ctx):
    """``(model, fit on the fitting half)`` with ``best``'s term added (refitted on all pixels);
    ``effects`` gets its entry, or the named effect it is a form of gets the term."""
    name = best["name"]
    nll_cur = evaluate(current, obs, ctx)
    new, nll_new = fit(best["model"], obs, ctx)
    daic = 2 * (new.n_parameters() - current.n_parameters()) - 2 * (nll_cur - nll_new)
    named = next((e for e in effects if e["name"] == CATALOGUE[name].effect), None)
    if named is not None:  # another form of a named effect: it joins it
        named["terms"].append(name)
    else:
        effects.append(
            {
                "name": CATALOGUE[name].effect,
                "terms": [name],
                "score": best["score"],
                "delta_aic": round(daic, 3),
                "heldout_gain": best["score"],
                "train_delta_aic": best["delta_aic"],
            }
        )
    return new, best["model"]


def _next_candidates(ranking, name, current, obs, ctx, before, only) -> list[str]:
    """The terms the next rounds try: those that gained something in this one (a term that did
    not help before the winner was modelled is not re-fitted), those the located statistics
    point at, and the other forms of the effects in the model."""
    again = [
        r["name"]
        for r in ranking
        if r["name"] != name and r["score"] is not None and r["score"] >= RETRY_GAIN
    ][:RETRY_MAX]
    again += [n for n in _signalled(current, obs, ctx, before) if n not in again]
    named = {CATALOGUE[n].effect for n in current.effects}
    again += [
        n
        for n in implemented()
        if CATALOGUE[n].effect in named and n not in current.effects and n not in again
    ]
    if only is not None:
        again = [n for n in again if n in only]
    return again


def _best_score(ranking: list) -> float:
    return max([r["score"] for r in ranking if r["score"] is not None], default=-math.inf)


def _one_name(ranking: list, effects: list, bar: float = -math.inf) -> list:
    """The ranking with a new effect's candidates significant only when they gain more than
    every form of the effects already named (which are ranked as they are) and than ``bar``
    (the forms' best gain in the round before, where they were ranked alone), and at least
    :data:`FORM_TOLERANCE` of the largest named effect's held-out gain (what a misfit of its
    form could leave)."""
    named = {e["name"] for e in effects}
    forms = [r["score"] for r in ranking if CATALOGUE[r["name"]].effect in named]
    bar = max([s for s in forms if s is not None] + [bar])
    gains = [e["heldout_gain"] for e in effects if e.get("heldout_gain") is not None]
    leftover = FORM_TOLERANCE * max(gains, default=0.0)
    for r in ranking:
        if CATALOGUE[r["name"]].effect in named or not r["significant"]:
            continue
        if r["score"] <= bar:
            r["significant"] = False
            r["below_named_forms"] = True
        elif r["score"] < leftover:
            r["significant"] = False
            r["within_form_tolerance"] = True
    return ranking


def _signalled(model, obs, ctx, before: dict) -> list[str]:
    """Terms whose located statistics are significant under ``model`` (the nulls of ``before``
    reused: no new bootstrap)."""
    with torch.no_grad():
        st = statistics(obs, predict(model, obs, scene=ctx.scene), ctx)
    for k, s in st.items():
        if k in before:
            s.null = before[k].null
    sig = {s.key for s in locate(st)}
    return [
        n
        for n, e in CATALOGUE.items()
        if e.implemented and n not in model.effects and any(a in sig for a in e.axes)
    ]


def _without(model, names: list[str]):
    """``model`` without the terms ``names``."""
    for n in names:
        model = model.without(n)
    return model


def prune(model, effects: list, obs, ctx):
    """Backward elimination, then the order: each term is dropped in turn from the final model
    (the rest refitted on all pixels); the one whose loss costs least is removed while that
    costs less than ``naming.MIN_DAIC`` of AIC (a term a later one made redundant), and the terms
    kept are ordered by what their removal costs (``drop_delta_aic``), most first: the term no
    other explains comes first, not the one that happened to win the first round (a term that
    partly stands in for the true one can gain more there). Each effect kept gets the final
    model without it, the rest refitted, as ``without_model`` (what it explains on its own,
    ``summary.on_its_own``; not for the report)."""
    nll_cur = evaluate(model, obs, ctx)
    drops: list = []
    while len(effects) > 1:
        fits = map_threads(
            lambda e, m=model: fit(_without(m, e.get("terms", [e["name"]])), obs, ctx), effects
        )
        drops = [
            (2 * (wo.n_parameters() - model.n_parameters()) + 2 * (nll_wo - nll_cur), e, wo, nll_wo)
            for e, (wo, nll_wo) in zip(effects, fits, strict=True)
        ]
        weakest = min(drops, key=lambda t: t[0])
        if weakest[0] >= MIN_DAIC:
            break
        model, nll_cur = weakest[2], weakest[3]
        effects = [x for x in effects if x is not weakest[1]]
        drops = []
    if not drops:  # one term left: nothing to order
        return model, effects
    for d_aic, e, wo, _ in drops:
        e["drop_delta_aic"] = round(d_aic, 3)
        e["without_model"] = wo
    return model, [e for _, e, _, _ in sorted(drops, key=lambda t: -t[0])]
