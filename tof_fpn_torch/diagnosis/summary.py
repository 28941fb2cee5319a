"""The content of ``report.json``: how well a model fits, where the located statistics depart,
and what each named effect is and explains."""

from __future__ import annotations

import math

import torch

from .catalogue import CATALOGUE
from .describe import where
from .likelihood import n_observations
from .locate import locate
from .prediction import predict

__all__ = [
    "also_consistent",
    "baseline_summary",
    "confidence",
    "describe_effects",
    "explained",
    "explained_share",
    "fit_summary",
    "hold_back",
    "located",
    "on_its_own",
    "report_content",
]

#: the verdict is ``high`` when the best candidate of another effect gained less than this share
#: of the named effect's held-out gain in the first round ...
CLEAR_SHARE: float = 0.5
#: ... and ``low`` when it gained at least this share (two readings about as good)
CLOSE_SHARE: float = 0.9
#: A further effect is named when it removes at least this share of the excess over the null of
#: a located statistic on its axes that is significant without it (:func:`on_its_own`): the
#: larger part of that structure is its own; what it leaves (up to this share, a relative misfit
#: of its form of about 70 %) is its form's misfit or another effect's
OWN_SHARE: float = 0.5


def fit_summary(model, obs, ctx, nll_all: float, heldout: float) -> dict:
    """How well ``model`` fits: NLL (all pixels), held-out NLL, parameters, AIC, residual rms."""
    with torch.no_grad():
        p = predict(model, obs, scene=ctx.scene)
    md, ma = ctx.mask_d, ctx.mask_a
    rd = obs.m_d - p.mu_d
    if p.wrap is not None:
        rd = rd - p.wrap * torch.round(rd / p.wrap)
    ra = (obs.m_a - p.mu_a) / p.mu_a
    n_test = n_observations(obs, ctx, "test")
    k = model.n_parameters()
    return {
        "heldout_nll": round(heldout, 3),
        "heldout_nll_per_observation": round(heldout / max(n_test, 1), 6),
        "nll": round(nll_all, 3),
        "parameters": round(k, 2),
        "aic": round(2 * k + 2 * nll_all, 3),
        "residual_rms_depth_mm": round(float(rd[md].pow(2).mean().sqrt()) * 1e3, 4),
        "residual_rms_amplitude_percent": round(float(ra[ma].pow(2).mean().sqrt()) * 100, 4),
        "observations": int(n_observations(obs, ctx)),
    }


def located(stats: dict, replicates: int) -> list[dict]:
    """Where each significant statistic departs (empty without a null: ``replicates`` < 0)."""
    return [where(s) for s in locate(stats)] if replicates >= 0 else []


def describe_effects(effects: list, model, obs, ctx, before: dict, after: dict) -> None:
    """Each effect's fitted values in physical units (``params``) and the located statistics it
    explains (``where``)."""
    with torch.no_grad():
        pred = predict(model, obs, scene=ctx.scene)
    for e in effects:
        terms = e.get("terms", [e["name"]])
        e["params"] = {}
        for t in terms:
            e["params"].update(CATALOGUE[t].describe(model, obs, pred))
        e["where"] = explained(terms[0], before, after)


def explained_share(effect: dict, without: dict, after: dict, keys=None) -> float | None:
    """The largest share of a located structure that ``effect`` removes on its own: over the
    statistics on its terms' axes (``Term.axes``; ``keys``: these instead) that are significant
    in ``without`` (the final model without the effect, its other terms refitted), the share of
    the excess over the null (``Stat.excess``) that is gone in ``after`` (the final model);
    None when none of them is significant without it."""
    if keys is None:
        keys = {k for t in effect.get("terms", [effect["name"]]) for k in CATALOGUE[t].axes}
    shares = [
        (without[k].excess - after[k].excess) / max(without[k].excess, 1e-12)
        for k in keys
        if k in without and k in after and without[k].significant
    ]
    return max(shares, default=None)


def on_its_own(effect: dict, before: dict, after: dict, without: dict | None = None) -> bool:
    """Whether a named effect explains a located structure on its own: a statistic on its
    terms' axes is significant without it (``without``: the located statistics of the final
    model without the effect, its other terms refitted; default ``before``, the baseline's) and
    the effect removes at least :data:`OWN_SHARE` of its excess (:func:`explained_share`). An
    effect none of whose axes is significant without it explains a structure of its own only
    if nothing significant is left.

    The physics: a real effect's form is never exactly the term's (a glossy lobe against the
    catalogue's relay, a measured cyclic error against a few harmonics). A relative misfit
    ``e`` of the form leaves about ``e^2`` of its structure's excess (the statistic is
    quadratic in the residual profile, as the held-out gain is; ``naming.FORM_TOLERANCE``), so
    the effect that is there leaves its statistics above the null band of a large structure
    while removing most of them; it must be named. A term that stands in for a part of a
    structure it does not explain removes little of the statistics along its own axes. The
    share is taken against the model without the effect, not against the baseline: two named
    terms on one axis (``cyclic_error`` and ``multipath`` on ``depth_mean|depth``) would each be
    credited with what the other removed."""
    w = before if without is None else without
    share = explained_share(effect, w, after)
    if share is not None:
        return share >= OWN_SHARE
    return not any(s.significant for s in after.values())


def hold_back(
    effects: list, before: dict, after: dict, without: dict | None = None
) -> tuple[list, list]:
    """``(named, held back)``: the first effect (what costs most to lose) is always named; a
    further one only when it explains a located structure on its own (:func:`on_its_own`;
    ``without``: effect name -> the located statistics of the final model without it, its
    other terms refitted; an effect not in it is compared with ``before``). The others stood
    in for a part of a structure no single term explains: the report puts them under
    ``unexplained`` with that structure, not among the names (the model keeps their terms)."""
    without = without or {}
    named, held = effects[:1], []
    for e in effects[1:]:
        (named if on_its_own(e, before, after, without.get(e["name"])) else held).append(e)
    return named, held


def confidence(
    effects: list, held: list, rankings: list, before: dict, after: dict, without=None
) -> dict:
    """How sure the verdict is: ``high``, ``moderate`` or ``low``, with the reasons (``before``
    / ``after``: the located statistics of the baseline and of the final model; ``without``:
    effect name -> those of the final model without it, as for :func:`hold_back`).

    With an effect named: the best first-round candidate of another effect (the runner-up) and
    its held-out gain as a share of the named effect's best term's; whether the named effect
    explains a located structure on its own (:func:`on_its_own`'s share, over its axes and the
    statistics it explains, ``where``);
    how many located statistics are still significant after the refit, and what was held back.
    ``high``: the runner-up below :data:`CLEAR_SHARE`, the structure explained, nothing left;
    ``low``: the runner-up at :data:`CLOSE_SHARE` or more, or its structure not explained and
    something held back; otherwise ``moderate``. With nothing named: ``high`` when no candidate
    gained half of ``naming.MIN_GAIN`` and nothing is located, else ``moderate``."""
    from .naming import MIN_GAIN

    first = rankings[0] if rankings else []
    left = sorted(k for k, s in after.items() if s.significant)
    if not effects:
        top = max([r["score"] for r in first if r["score"] is not None], default=0.0)
        level = "high" if top < 0.5 * MIN_GAIN and not left else "moderate"
        return {"level": level, "best_candidate_gain": round(top, 3), "residual_statistics": left}
    name = effects[0]["name"]
    own = [r["score"] for r in first if CATALOGUE[r["name"]].effect == name and r["score"]]
    other = [r for r in first if CATALOGUE[r["name"]].effect != name and r["score"] is not None]
    runner = max(other, key=lambda r: r["score"], default=None)
    best = max(own, default=None)
    share = None
    if runner is not None and best is not None and best > 0:
        share = max(runner["score"], 0.0) / best
    keys = {k for t in effects[0].get("terms", [name]) for k in CATALOGUE[t].axes}
    keys |= {w["statistic"] for w in effects[0].get("where", [])}
    w = (without or {}).get(name, before)
    share_own = explained_share(effects[0], w, after, keys)
    explains = share_own is not None and share_own >= OWN_SHARE
    if share is not None and share >= CLOSE_SHARE or (held and not explains):
        level = "low"
    elif (share is None or share < CLEAR_SHARE) and explains and not left and not held:
        level = "high"
    else:
        level = "moderate"
    return {
        "level": level,
        "runner_up": None if runner is None else CATALOGUE[runner["name"]].effect,
        "runner_up_share": None if share is None else round(share, 4),
        "explains_its_structure": explains,
        "residual_statistics": left,
        "held_back": [e["name"] for e in held],
    }


def report_content(
    effects, fits, rankings, before, after, obs, ctx, replicates: int, held=None, without=None
) -> dict:
    """The ``report.json`` content (without ``seconds``); ``held``: the effects held back
    (:func:`hold_back`), reported under ``unexplained``; ``without``: effect name -> the located
    statistics of the final model without it (:func:`hold_back`)."""
    held = held or []
    return {
        "effects": [
            {k: e[k] for k in ("name", "terms", "score", "delta_aic", "params", "where") if k in e}
            for e in effects
        ],
        "verdict": ([e["name"] for e in effects] or ["none"]) + (["unexplained"] if held else []),
        "confidence": confidence(effects, held, rankings, before, after, without),
        "held_back": [
            {
                "stood_in_by": e["name"],
                "terms": e.get("terms", [e["name"]]),
                "score": e.get("score"),
                "structure": e.get("where", []),
            }
            for e in held
        ],
        "also_consistent_with": also_consistent(effects + held, rankings),
        "fit": fits,
        "located_before": located(before, replicates),
        "located_after": located(after, replicates),
        "unexplained": [where(s) for s in locate(after)]
        if effects or any(s.significant for s in before.values())
        else [],
        "candidates": rankings,
        "not_implemented": [n for n, e in CATALOGUE.items() if not e.implemented],
        "recording": {
            "frames": obs.frames,
            "height": obs.shape[0],
            "width": obs.shape[1],
            "scene_estimated": obs.scene_estimated,
            "notes": obs.notes,
            "depth_pixels": int(ctx.mask_d.sum()),
            "amplitude_pixels": int(ctx.mask_a.sum()),
        },
        "bootstrap_replicates": replicates,
    }


def also_consistent(effects: list, rankings: list) -> list[str]:
    """The effects not named whose candidates were significant in some round (a term that gains
    on its own but not beyond the effects named: it stands in for their misfit, or it is
    another reading of the same data), strongest first."""
    named = {e["name"] for e in effects}
    out: dict[str, float] = {}
    for ranking in rankings:
        for r in ranking:
            eff = CATALOGUE[r["name"]].effect
            held = r.get("below_named_forms", False) or r.get("within_form_tolerance", False)
            ok = r["significant"] or held
            if ok and eff not in named and r["score"] is not None:
                out[eff] = max(out.get(eff, -math.inf), r["score"])
    return sorted(out, key=lambda k: -out[k])


def explained(name: str, before: dict, after: dict) -> list[dict]:
    """The located statistics this effect explains: its catalogue axes first, then any other
    statistic that was significant before and is not any more."""
    keys = [k for k in CATALOGUE[name].axes if k in before]
    keys += [
        k
        for k, s in before.items()
        if s.significant and k not in keys and k in after and not after[k].significant
    ]
    out = []
    for k in keys[:4]:
        b = where(before[k])
        a = after[k]
        b["after"] = {
            "value": round(a.value, 3),
            "p": a.p,
            "excess_sigma": round(a.excess, 2),
            "null_band_95": [round(x, 3) for x in a.band()],
            "inside_null_band": bool(a.band()[0] <= a.value <= a.band()[1]) or a.p > 0.05,
        }
        out.append(b)
    return out


def baseline_summary(model) -> dict:
    """What the fitted baseline holds besides the issue's core: the catalogue terms the
    recording states (``stated``: their values are not fitted) or that an estimated scene
    implies, and the read-out pattern (periodic offsets in e-, and where the recording states
    the simulator's read-out, the random column offsets in DN and gains)."""
    v = model.values
    out = {
        "terms": list(model.effects),
        "stated": sorted(model.fixed),
        "readout_periodic_e": {
            k.split(".")[1]: round(float(v[k]), 4)
            for k in ("readout_fpn.cos_2pi3", "readout_fpn.sin_2pi3", "readout_fpn.cos_pi")
        },
        "random_columns": model.random_columns,
    }
    if model.random_columns:
        out["readout_random_columns"] = {
            "offset_rms_dn": round(float(v.get("readout_fpn.random_offset_rms", 0.0)), 4),
            "gain_rms": round(float(v.get("readout_fpn.random_gain_rms", 0.0)), 6),
            "effective_parameters": round(float(v.get("readout_fpn.columns_dof", 0.0)), 2),
        }
    return out
