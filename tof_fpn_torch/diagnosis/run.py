"""``diagnose``: fit, locate, name, model, refit -- until nothing significant is left."""

from __future__ import annotations

import math
import os
import time
from contextlib import contextmanager
from dataclasses import dataclass, field

import torch

from .. import constants as K
from ..io import Recording, read_recording, read_scene
from .catalogue import CATALOGUE, REVEALED_WITHOUT_SCENE
from .data import Observations, observe
from .describe import describe_effect, where
from .fit import evaluate, fit, init_model, robust_start
from .likelihood import Context, make_context, n_observations
from .locate import Stat, bootstrap, locate, statistics
from .model import DiagnosisModel, predict
from .naming import rank
from .persist import adapt_model, load_model
from .threads import map_threads

__all__ = ["Diagnosis", "diagnose"]


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


def _fit_summary(model, obs, ctx, nll_all: float, heldout: float) -> dict:
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


def _located(stats: dict, replicates: int) -> list[dict]:
    return [where(s) for s in locate(stats)] if replicates >= 0 else []


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
            "recording must be a tof_fpn_torch.io.Recording or the path of a recording .npz, "
            f"got {type(recording).__name__}"
        )
    if not isinstance(recording, Recording):
        recording = read_recording(recording)
    if scene is not None and not hasattr(scene, "depth"):
        scene = read_scene(scene)
    return recording, scene


def diagnose(
    recording,
    scene=None,
    baseline=None,
    *,
    max_effects: int = 3,
    replicates: int = K.DIAG_BOOTSTRAP,
    seed: int = 0,
    threads: int | None = 1,
) -> Diagnosis:
    """Diagnose ``recording`` against the simulator.

    Args:
        recording: a :class:`~tof_fpn_torch.io.Recording` or the path of a recording ``.npz``.
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
        if baseline is None:
            model = init_model(obs, obs.scene())
            if obs.scene_estimated:  # every pixel's amplitude carries its own reflectance
                model = model.with_effect("pixel_gain", {"pixel_gain.rms": K.DIAG_TEXTURE_RMS})
                obs.notes.append(
                    "the baseline holds a per-pixel amplitude texture (pixel_gain): without a "
                    "scene, reflectance texture and pixel gain cannot be told apart"
                )
        else:
            model = adapt_model(
                load_model(baseline) if not isinstance(baseline, DiagnosisModel) else baseline, obs
            )
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
        start_values = robust_start(init, obs, ctx, model)
        if not bool(ctx.mask_d.any()):
            raise ValueError("no pixel has a clear enough signal for the depth likelihood")
        base = model
        nll_base = evaluate(base, obs, ctx)
        before = _stats(base, obs, ctx, replicates, seed)
        rankings, effects = [], []
        ranking, base_train = rank(base, obs, ctx, start_values=start_values, only=only)
        heldout_before = evaluate(base_train, obs, ctx, "test")
        current, train_model = base, base_train
        for _ in range(max_effects):
            rankings.append([{k: v for k, v in r.items() if k != "model"} for r in ranking])
            best = next((r for r in ranking if r["significant"]), None)
            if best is None:
                break
            name = best["name"]
            nll_cur = evaluate(current, obs, ctx)
            new, nll_new = fit(best["model"], obs, ctx)
            effects.append(
                {
                    "name": name,
                    "score": best["score"],
                    "delta_aic": round(
                        2 * (new.n_parameters() - current.n_parameters()) - 2 * (nll_cur - nll_new),
                        3,
                    ),
                    "heldout_gain": best["score"],
                    "train_delta_aic": best["delta_aic"],
                }
            )
            current = new
            train_model = best["model"]
            if len(effects) == max_effects:
                break
            # the next round tries the terms that gained something in this one (a term that
            # did not help before the winner was modelled is not re-fitted)
            again = [
                r["name"]
                for r in ranking
                if r["name"] != name and r["score"] is not None and r["score"] >= K.DIAG_RETRY_GAIN
            ][: K.DIAG_RETRY_MAX]
            again += [n for n in _signalled(current, obs, ctx, before) if n not in again]
            if only is not None:
                again = [n for n in again if n in only]
            ranking, train_model = rank(current, obs, ctx, only=again, start_values=start_values)
        if len(effects) > 1:  # backward check: a term a later one made redundant is dropped
            current, effects = _prune(current, effects, obs, ctx)
        if effects:
            train_model, _ = fit(current, obs, ctx, "train")
        heldout_after = evaluate(train_model, obs, ctx, "test")
        after = _stats(current, obs, ctx, replicates, seed + 7) if effects else before
        with torch.no_grad():
            pred = predict(current, obs, scene=ctx.scene)
        for e in effects:
            e["params"] = describe_effect(e["name"], current, obs, pred)
            e["where"] = _where(e["name"], before, after)
        report = {
            "effects": [
                {k: e[k] for k in ("name", "score", "delta_aic", "params", "where")}
                for e in effects
            ],
            "verdict": [e["name"] for e in effects] or ["none"],
            "fit": {
                "before": _fit_summary(base, obs, ctx, nll_base, heldout_before),
                "after": _fit_summary(
                    current, obs, ctx, evaluate(current, obs, ctx), heldout_after
                ),
            },
            "located_before": _located(before, replicates),
            "located_after": _located(after, replicates),
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
            "seconds": round(time.perf_counter() - t0, 2),
        }
    return Diagnosis(report, base, current, obs, ctx, before, after, rankings)


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


def _prune(model, effects: list, obs, ctx):
    """Backward elimination, then the order: each term is dropped in turn from the final model
    (the rest refitted on all pixels); the one whose loss costs least is removed while that
    costs less than ``DIAG_MIN_DAIC`` of AIC (a term a later one made redundant), and the terms
    kept are ordered by what their removal costs (``drop_delta_aic``), most first: the term no
    other explains comes first, not the one that happened to win the first round (a term that
    partly stands in for the true one can gain more there)."""
    nll_cur = evaluate(model, obs, ctx)
    drops: list = []
    while len(effects) > 1:
        fits = map_threads(lambda e, m=model: fit(m.without(e["name"]), obs, ctx), effects)
        drops = [
            (2 * (wo.n_parameters() - model.n_parameters()) + 2 * (nll_wo - nll_cur), e, wo, nll_wo)
            for e, (wo, nll_wo) in zip(effects, fits, strict=True)
        ]
        weakest = min(drops, key=lambda t: t[0])
        if weakest[0] >= K.DIAG_MIN_DAIC:
            break
        model, nll_cur = weakest[2], weakest[3]
        effects = [x for x in effects if x is not weakest[1]]
        drops = []
    if not drops:  # one term left: nothing to order
        return model, effects
    for d_aic, e, _, _ in drops:
        e["drop_delta_aic"] = round(d_aic, 3)
    return model, [e for _, e, _, _ in sorted(drops, key=lambda t: -t[0])]


def _where(name: str, before: dict, after: dict) -> list[dict]:
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


def _finite(x) -> float:
    return x if math.isfinite(x) else None
