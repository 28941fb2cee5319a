"""``diagnose``: fit, locate, name, model, refit -- until nothing significant is left."""

from __future__ import annotations

import math
import os
import time
from contextlib import contextmanager
from dataclasses import dataclass, field

import torch

from ..io import Recording, read_any_recording, read_scene
from .catalogue import CATALOGUE, REVEALED_WITHOUT_SCENE, implemented
from .data import Observations, observe
from .fit import FIT_TOL, evaluate, fit, init_model, robust_start
from .likelihood import Context, make_context
from .locate import Stat, bootstrap, locate, statistics
from .model import DiagnosisModel, predict
from .naming import FORM_TOLERANCE, MIN_DAIC, rank
from .persist import adapt_model, load_model
from .summary import baseline_summary, describe_effects, fit_summary, report_content
from .threads import map_threads

__all__ = ["BOOTSTRAP", "RETRY_GAIN", "RETRY_MAX", "Diagnosis", "diagnose"]

#: Parametric-bootstrap recordings per null distribution.
BOOTSTRAP: int = 8
#: After a term is added, the next round re-fits only the candidates whose held-out gain was at
#: least this many nats (at most ``RETRY_MAX`` of them, best first), and those whose located
#: statistics are still significant.
RETRY_GAIN: float = 1.0
RETRY_MAX: int = 6


@dataclass
class Diagnosis:
    """What :func:`diagnose` found: ``report`` (the ``report.json`` content), the fitted
    ``baseline`` and final ``model``, the observations, the located statistics ``before`` /
    ``after`` and the candidate ``rankings`` of every round."""

    report: dict
    baseline: DiagnosisModel
    model: DiagnosisModel
    obs: Observations
    ctx: Context
    before: dict
    after: dict
    rankings: list = field(default_factory=list)

    @property
    def effects(self) -> list[str]:
        """Names of the effects found, best first (empty: ``none``)."""
        return [e["name"] for e in self.report["effects"]]

    def files(self, figures: bool = True) -> dict[str, bytes]:
        """Every output file as ``{name: bytes}``: report.json, report.md, model.json, figures."""
        from .report import render

        return render(self, figures)

    def write(self, out_dir, figures: bool = True) -> list[str]:
        """Write the outputs into ``out_dir`` (all or nothing); returns the paths written."""
        from .report import write_outputs

        return write_outputs(self.files(figures), out_dir)


@contextmanager
def _threads(n: int | None):
    old = torch.get_num_threads()
    if n is not None:
        torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(old)


def _stats(model, obs, ctx, replicates: int, seed: int) -> dict[str, Stat]:
    with torch.no_grad():
        st = statistics(obs, predict(model, obs, scene=ctx.scene), ctx)
    if replicates > 0:
        bootstrap(model, obs, ctx, st, replicates, seed)
    locate(st)
    return st


def _load(recording, scene):
    if not isinstance(recording, (Recording, str, os.PathLike)):
        raise ValueError(
            "recording must be a tof_fpn_torch.io.Recording or the path of a recording .npz or "
            "camera file, "
            f"got {type(recording).__name__}"
        )
    if not isinstance(recording, Recording):
        recording = read_any_recording(recording, frame_files=False)
    if scene is not None and not hasattr(scene, "depth"):
        scene = read_scene(scene)
    return recording, scene


def diagnose(
    recording,
    scene=None,
    baseline=None,
    *,
    max_effects: int = 3,
    replicates: int = BOOTSTRAP,
    seed: int = 0,
    threads: int | None = 1,
) -> Diagnosis:
    """Diagnose ``recording`` against the simulator.

    Args:
        recording: a :class:`~tof_fpn_torch.io.Recording` or the path of a recording ``.npz``
            or of a camera's own file (``.mkv``, ROS bag, ADI ``.bin``; ``io.read_any_recording``).
        scene: the ground truth (:class:`~tof_fpn_torch.io.SceneData`, a one-scene
            :class:`~tof_fpn_torch.sim.Scene` or a scene ``.npz`` path); ``None``: estimated from
            the recording (temporal median, edge-aware smoothing; see docs/diagnosis.md for what
            that can and cannot reveal).
        baseline: starting model (a :class:`DiagnosisModel` or the path of a ``model.json`` a
            diagnosis wrote); default the issue's baseline.
        max_effects: most terms added (the loop also stops when no candidate is significant).
        replicates: parametric-bootstrap recordings per null distribution (0: the analytic
            chi^2 null of the Gaussian model).
        seed: seed of the bootstrap.
        threads: torch threads during the diagnosis (restored afterwards; None: unchanged).

    Returns:
        :class:`Diagnosis`; ``.report`` is the ``report.json`` dict
        ``{"effects": [{"name", "score", "delta_aic", "params", "where"}, ...],
        "fit": {"before", "after"}, ...}``.
    """
    t0 = time.perf_counter()
    recording, scene = _load(recording, scene)
    with _threads(threads):
        obs = observe(recording, scene)
        only = REVEALED_WITHOUT_SCENE if obs.scene_estimated else None
        base, ctx, start_values = _fit_baseline(_baseline(obs, baseline), obs)
        nll_base = evaluate(base, obs, ctx)
        before = _stats(base, obs, ctx, replicates, seed)
        ranking, base_train = rank(base, obs, ctx, start_values=start_values, only=only)
        heldout_before = evaluate(base_train, obs, ctx, "test")
        current, train_model, effects, rankings = _forward(
            base, base_train, ranking, obs, ctx, before, start_values, only, max_effects
        )
        if len(effects) > 1:  # backward check: a term a later one made redundant is dropped
            current, effects = _prune(current, effects, obs, ctx)
        if effects:
            train_model, _ = fit(current, obs, ctx, "train")
        heldout_after = evaluate(train_model, obs, ctx, "test")
        after = _stats(current, obs, ctx, replicates, seed + 7) if effects else before
        describe_effects(effects, current, obs, ctx, before, after)
        fits = {
            "before": fit_summary(base, obs, ctx, nll_base, heldout_before),
            "after": fit_summary(current, obs, ctx, evaluate(current, obs, ctx), heldout_after),
        }
        report = report_content(effects, fits, rankings, before, after, obs, ctx, replicates)
        report["baseline"] = baseline_summary(base)
        report["seconds"] = round(time.perf_counter() - t0, 2)
    return Diagnosis(report, base, current, obs, ctx, before, after, rankings)


def _baseline(obs: Observations, baseline) -> DiagnosisModel:
    """The starting model: ``baseline`` (a model or a ``model.json`` path) fitted to ``obs``'s
    camera, or the issue's baseline from the data (with the terms that a recording without a
    scene holds from the start, ``Term.baseline_without_scene``)."""
    if baseline is not None:
        if not isinstance(baseline, DiagnosisModel):
            baseline = load_model(baseline)
        return adapt_model(baseline, obs)
    model = init_model(obs, obs.scene())
    if obs.simulator:
        model.random_columns = True
        obs.notes.append(
            "the recording states that the package's simulator made it (sim_camera): its "
            "read-out is the simulator's ReadoutFPN, whose default has random column offsets "
            "and gains besides the periodic ones; the baseline holds them (readout_fpn.*)"
        )
    if obs.frames < 2:
        # one frame has no temporal spread: the shot-noise share of the noise (the conversion
        # gain) cannot be told from the read noise, and the fit drifts along that direction
        model.fixed = model.fixed | frozenset({"camera.conversion_gain"})
        obs.notes.append(
            "a single frame: the conversion gain is held at its value from the data's noise "
            f"level ({model.values['camera.conversion_gain']:.4g} e-/DN), not fitted"
        )
    for term in CATALOGUE.values():
        extra = term.baseline_stated(obs, model)
        fixed = extra is not None
        if extra is None and obs.scene_estimated:
            extra = term.baseline_without_scene()
        if extra is not None:
            values, note = extra
            model = model.with_effect(term.name, values)
            if fixed:  # what the recording states is not fitted
                model.fixed = model.fixed | frozenset(values)
            obs.notes.append(note)
    return model


def _fit_baseline(model: DiagnosisModel, obs: Observations):
    """``(fitted model, context, robust starting values)``: the likelihood's pixel masks, the
    baseline fitted on them, and the core values a gross misfit cannot drag away."""
    with torch.no_grad():
        p0 = predict(model, obs)
    ctx = make_context(obs, p0.a0 / p0.s)
    # the masks come from the starting model (its amplitude scale and noise level are robust
    # medians of the data), so that a baseline that misfits badly cannot shrink them ...
    init = model
    model, _ = fit(model, obs, ctx)
    # ... and may only grow: a pixel whose signal is clear under the fitted model joins too
    # (the starting model's robust amplitude scale can sit below a bright corner's, which
    # hid e.g. wrapped far pixels with a fitted SNR above the cut); refit on the union
    with torch.no_grad():
        p1 = predict(model, obs)
    grown = make_context(obs, torch.maximum(p0.a0 / p0.s, p1.a0 / p1.s))
    if bool((grown.mask_d & ~ctx.mask_d).any()) or bool((grown.mask_a & ~ctx.mask_a).any()):
        ctx = grown
        model, _ = fit(model, obs, ctx)
    start_values, robust = robust_start(init, obs, ctx, model)
    if robust is not None:
        # the fit on all pixels can settle in a basin the outliers bent (the noise law and the
        # read-out columns absorbing a misfit); from the robust fit it may reach a better one
        alt, nll_alt = fit(robust, obs, ctx)
        if nll_alt < evaluate(model, obs, ctx) - FIT_TOL:
            model = alt
    if not bool(ctx.mask_d.any()):
        raise ValueError("no pixel has a clear enough signal for the depth likelihood")
    return model, ctx, start_values


def _forward(base, base_train, ranking, obs, ctx, before, start_values, only, max_effects):
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
        ranking, train_model = rank(current, obs, ctx, only=candidates, start_values=start_values)
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


def _prune(model, effects: list, obs, ctx):
    """Backward elimination, then the order: each term is dropped in turn from the final model
    (the rest refitted on all pixels); the one whose loss costs least is removed while that
    costs less than ``naming.MIN_DAIC`` of AIC (a term a later one made redundant), and the terms
    kept are ordered by what their removal costs (``drop_delta_aic``), most first: the term no
    other explains comes first, not the one that happened to win the first round (a term that
    partly stands in for the true one can gain more there)."""
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
    for d_aic, e, _, _ in drops:
        e["drop_delta_aic"] = round(d_aic, 3)
    return model, [e for _, e, _, _ in sorted(drops, key=lambda t: -t[0])]
