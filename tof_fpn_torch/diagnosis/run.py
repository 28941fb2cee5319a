"""``diagnose``: fit, locate, name, model, refit -- until nothing significant is left."""

from __future__ import annotations

import os
import time
from contextlib import contextmanager
from dataclasses import dataclass, field

import torch

from ..io import Recording, read_any_recording, read_scene
from .catalogue import CATALOGUE, REVEALED_WITHOUT_SCENE
from .data import Observations, observe
from .fit import FIT_TOL, evaluate, fit, init_model, robust_start
from .incidence import incidence_open
from .likelihood import Context, make_context
from .locate import Stat, bootstrap, locate, statistics
from .model import DiagnosisModel
from .naming import rank
from .persist import adapt_model, load_model
from .poses import one_pose
from .prediction import predict
from .rounds import forward, prune
from .summary import (
    baseline_summary,
    describe_effects,
    fit_summary,
    hold_back,
    report_content,
)

__all__ = ["BOOTSTRAP", "Diagnosis", "diagnose"]

#: Parametric-bootstrap recordings per null distribution.
BOOTSTRAP: int = 8


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


def _stats_without(effects: list, obs, ctx, after: dict) -> dict:
    """Effect name -> the located statistics of the final model without the effect, its other
    terms refitted (``prune``'s ``without_model``, taken off the entries), with the nulls of
    ``after`` (no new bootstrap: the model differs by one effect)."""
    out = {}
    for e in effects:
        wo = e.pop("without_model", None)
        if wo is None:
            continue
        with torch.no_grad():
            st = statistics(obs, predict(wo, obs, scene=ctx.scene), ctx)
        for k, s in st.items():
            if k in after:
                s.null = after[k].null
        locate(st)
        out[e["name"]] = st
    return out


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
            that can and cannot reveal); of a recording whose frames show several poses (the
            camera or the scene moved), the frames of the largest pose are diagnosed and a note
            says which (``diagnosis.poses``).
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
    pose_note = None
    if scene is None:  # the scene is estimated from the frames: those of one pose
        recording, pose_note = one_pose(recording)
    with _threads(threads):
        obs = observe(recording, scene)
        if pose_note is not None:
            obs.notes.append(pose_note)
        only = REVEALED_WITHOUT_SCENE if obs.scene_estimated else None
        base, ctx, start_values = _fit_baseline(_baseline(obs, baseline), obs)
        nll_base = evaluate(base, obs, ctx)
        before = _stats(base, obs, ctx, replicates, seed)
        ranking, base_train = rank(base, obs, ctx, start_values=start_values, only=only)
        heldout_before = evaluate(base_train, obs, ctx, "test")
        current, train_model, effects, rankings = forward(
            base, base_train, ranking, obs, ctx, before, start_values, only, max_effects
        )
        forward_model = current
        if len(effects) > 1:  # backward check: a term a later one made redundant is dropped
            current, effects = prune(current, effects, obs, ctx)
        # the forward rounds end with the model's fit on the fitting half (the last ranking's),
        # unless they stopped at the most effects (the winner's fit there) or the backward
        # check dropped a term
        if effects and (len(effects) >= max_effects or current is not forward_model):
            train_model, _ = fit(current, obs, ctx, "train")
        heldout_after = evaluate(train_model, obs, ctx, "test")
        after = _stats(current, obs, ctx, replicates, seed + 7) if effects else before
        describe_effects(effects, current, obs, ctx, before, after)
        without = _stats_without(effects, obs, ctx, after)
        effects, held = hold_back(effects, before, after, without)
        fits = {
            "before": fit_summary(base, obs, ctx, nll_base, heldout_before),
            "after": fit_summary(current, obs, ctx, evaluate(current, obs, ctx), heldout_after),
        }
        report = report_content(
            effects, fits, rankings, before, after, obs, ctx, replicates, held, without
        )
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
            model = model.with_effect(term, values)
            if fixed:  # what the recording states is not fitted
                model.fixed = model.fixed | frozenset(values)
            obs.notes.append(note)
    return model


def _trusted_snr(model: DiagnosisModel, obs: Observations, pred) -> torch.Tensor:
    """The predicted SNR (``A_0 / s``) that the likelihood's masks are cut at, 0 where the
    baseline's angle of incidence leaves a pixel's light open (``incidence.incidence_open``)."""
    snr = pred.a0 / pred.s
    open_ = incidence_open(obs.scene(), model.values)
    return snr if open_ is None else snr.masked_fill(open_, 0.0)


def _fit_baseline(model: DiagnosisModel, obs: Observations):
    """``(fitted model, context, robust starting values)``: the likelihood's pixel masks, the
    baseline fitted on them, and the core values a gross misfit cannot drag away."""
    with torch.no_grad():
        p0 = predict(model, obs)
    ctx = make_context(obs, _trusted_snr(model, obs, p0))
    # the masks come from the starting model (its amplitude scale and noise level are robust
    # medians of the data), so that a baseline that misfits badly cannot shrink them ...
    init = model
    model, _ = fit(model, obs, ctx)
    # ... and may only grow: a pixel whose signal is clear under the fitted model joins too
    # (the starting model's robust amplitude scale can sit below a bright corner's, which
    # hid e.g. wrapped far pixels with a fitted SNR above the cut); refit on the union
    with torch.no_grad():
        p1 = predict(model, obs)
    snr = torch.maximum(_trusted_snr(model, obs, p0), _trusted_snr(model, obs, p1))
    grown = make_context(obs, snr)
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
