"""The interface of a catalogue term (:class:`Term`) and what the terms of the mean chain share
within one prediction (:class:`Chain`).

A term is one class: its fitted parameters (``specs``), the located statistics that point at it
(``axes``), its starting values, how it enters the model's prediction, its simulator term and
its description for the report. The shared machinery (the prediction in
:mod:`~tof_fpn_torch.diagnosis.model`, the likelihood, the fit, the ranking) asks every term in the
model through the hooks below and never by name; a hook a term does not override leaves the model
as it is. How to add one: :mod:`~tof_fpn_torch.diagnosis.catalogue`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import torch

from ..params import ParamSpec

__all__ = [
    "ENTERS",
    "Chain",
    "ClosedFormMapTerm",
    "Term",
    "depth_residuals",
    "least_squares",
    "r4",
    "shrink_to_zero",
]

#: how a term can enter the model (``Term.enters``) and the hook that makes it so
ENTERS: dict[str, str] = {
    "chain": "simulator_term in the noise-free mean chain (apply_mean)",
    "variance": "depth_variance / depth_variance_limit / amplitude_sd / depth_mean_sd",
    "frames": "frame_means / outlier_rate / depth_tail",
    "mixture": "edge_mixture",
    "wrap": "wrap_range",
}


@dataclass
class Chain:
    """What the terms of the noise-free mean chain share within one prediction: the photons'
    samples (``photons``, e-), the two cached unit images they were made from (``units``: active
    and ambient light at unit responsivity, ``key``: their cache key), the ambient irradiance and
    responsivity they were scaled with, and the per-sample noise variance (e-^2) once a term has
    changed it (``sample_var``, None: shot and read noise as usual)."""

    photons: torch.Tensor
    units: tuple
    key: tuple
    ambient: object
    responsivity: object
    sample_var: torch.Tensor | None = None


class Term:
    """One catalogue term. Subclasses set the class attributes and override
    :meth:`simulator_term`, :meth:`initial_values` and :meth:`describe`, plus the hooks of how
    they enter the model (``enters``). Values ``v`` map ``"owner.field"`` keys to floats or
    tensors (tensors keep the autograd graph while the model is fitted)."""

    #: the term's key in the catalogue; every key of ``specs`` starts with ``name + "."``
    name: ClassVar[str] = ""
    #: the effect the report names when this term is in the model: its ``name``, or for a
    #: flexible member of an effect (another functional form of the same physics) the name of
    #: that effect (the report names the signature, not the form)
    signature: ClassVar[str] = ""
    #: the fitted scalars (empty: nothing fitted by L-BFGS, e.g. closed-form profiles)
    specs: ClassVar[tuple[ParamSpec, ...]] = ()
    #: how it enters the model, a key of :data:`ENTERS`
    enters: ClassVar[str] = ""
    #: name of its simulator term (its place in ``sim.STAGE``); None: no simulator term
    sim_name: ClassVar[str | None] = None
    #: the located statistics (``channel|axis``) that point at it
    axes: ClassVar[tuple[str, ...]] = ()
    #: what it is, one line for the report and the docs
    about: ClassVar[str] = ""
    #: False: listed in the vocabulary, not fitted (the report names it ``not_implemented``)
    implemented: ClassVar[bool] = True
    #: tried when the scene is estimated from the recording (its signature survives smoothing)
    revealed_without_scene: ClassVar[bool] = False
    #: slow to fit: started first when the candidates run in threads
    slow: ClassVar[bool] = False
    #: fitted in closed form (:meth:`update_closed_form`): not started from a grid, no second
    #: start from the robust core values
    closed_form: ClassVar[bool] = False
    #: its starting values are computed again from the robust core values for the second start
    #: (they depend on the core values' scale, e.g. a level in e-)
    restarts_from_robust_values: ClassVar[bool] = False
    #: keys of ``DiagnosisModel.profiles`` it owns (dropped with it)
    profile_keys: ClassVar[tuple[str, ...]] = ()

    @property
    def effect(self) -> str:
        """The effect the report names (``signature``, default ``name``)."""
        return self.signature or self.name

    # --- what every term implements -------------------------------------------------------------

    def simulator_term(self, v: dict, model):
        """Its simulator term (``sim``) with values ``v``; None when it has none."""
        raise NotImplementedError

    def initial_values(self, model, obs, ctx, pred) -> list[dict]:
        """Starting values to try (each a dict over its ``specs`` keys; empty: the term cannot be
        fitted to ``obs``). ``pred``: ``model``'s prediction, ``ctx.mask_d`` / ``ctx.mask_a``
        the pixels of the likelihood."""
        raise NotImplementedError

    def describe(self, model, obs, pred) -> dict:
        """Its fitted values in physical units (and a few derived numbers) for ``report.json``."""
        raise NotImplementedError

    # --- how it enters the prediction (defaults: not at all) ---------------------------------------

    def apply_mean(self, state, v: dict, model, chain: Chain):
        """``chain`` terms: the noise-free samples after this term (default: its simulator term
        applied); others pass ``state`` through."""
        if self.enters != "chain":
            return state
        t = self.simulator_term(v, model)
        return state if t is None else t.apply(state)

    def depth_variance(self, v: dict):
        """Variance (m^2) added to every depth reading, or None."""
        return None

    def depth_variance_limit(self, r_cam: float):
        """Largest depth variance (m^2) a reading can have (applied after every addition), or
        None; ``r_cam``: the camera's unambiguous range (m)."""
        return None

    def amplitude_sd(self, v: dict, mu_a: torch.Tensor):
        """Sd of a random effect fixed over time on each pixel's amplitude mean, or None."""
        return None

    def depth_mean_sd(self, v: dict, a0: torch.Tensor, k: float):
        """Sd (m) of a random effect fixed over time on each pixel's depth mean, or None;
        ``a0``: the noise-free amplitude (DN), ``k``: radians of phase per metre of depth."""
        return None

    def wrap_range(self, v: dict):
        """The range (m) the depth is folded into, or None."""
        return None

    def frame_means(self, v: dict, obs, model=None):
        """Per-frame change of the means: ``(depth shift (T, 1), amplitude factor (T, 1))``, or
        None (``model``: for a term whose per-frame values are profiles of the model)."""
        return None

    def edge_mixture(self, v: dict):
        """Probability that a pixel on a depth edge of the scene is a mixture of its own return
        and its neighbour's across the edge with a free share (uniform in (0, 1)), or None."""
        return None

    def clip_level(self, v: dict):
        """The raw level (DN) where the samples clip, or None."""
        return None

    def region(self, obs):
        """The pixels (H, W bool) this term alone acts on (e.g. the depth edges), or None: the
        ranking also starts its fit from the core fitted without them."""
        return None

    def outlier_rate(self, v: dict):
        """Share of frame-pixels that carry no information (a uniform mixture component), or
        None."""
        return None

    def depth_tail(self, v: dict):
        """``1 / dof`` of a Student-t law of every depth reading about its mean (scaled to the
        predicted sd: a heavy-tailed noise), or None (Gaussian)."""
        return None

    def signature_share(self, obs, ctx, pred):
        """For a term that enters as a spread: the share (0 to 1) of ``pred``'s misfit that has
        its signature (:mod:`~tof_fpn_torch.diagnosis.signature`); the ranking scales its
        held-out gain by it. None: not scaled."""
        return None

    # --- closed-form terms ---------------------------------------------------------------------

    def update_closed_form(self, model, obs, ctx, pred, sel: str):
        """``model`` with this term's closed-form estimates from ``pred`` on the ``sel`` pixels
        (``closed_form`` terms; called by the fit between L-BFGS rounds)."""
        return model

    def effective_parameters(self, values: dict) -> float:
        """Parameters it counts beyond ``specs`` (closed-form estimates: their effective degrees
        of freedom)."""
        return 0.0

    # --- what the recording states -----------------------------------------------------------------

    def baseline_stated(self, obs, model):
        """``(values, note)`` when the recording states this physics of its camera (e.g. its
        full well), so that the baseline holds it from the start and it is never a finding (the
        note goes into the report), else None. ``model``: the baseline with its starting values."""
        return None

    # --- the baseline without a scene -------------------------------------------------------------

    def baseline_without_scene(self):
        """``(values, note)`` when the baseline holds this term as soon as the scene is estimated
        from the recording (the note goes into the report), else None."""
        return None


# --- helpers the terms share ---------------------------------------------------------------------


def least_squares(x: torch.Tensor, y: torch.Tensor, w: torch.Tensor) -> float:
    """The weighted least-squares slope of ``y`` on ``x`` through zero (0 when ``x`` is 0)."""
    den = float((w * x * x).sum())
    return float((w * x * y).sum()) / den if den > 0 else 0.0


def shrink_to_zero(mean: torch.Tensor, noise: torch.Tensor, has=None):
    """Empirical Bayes for random effects about zero: ``mean`` (e.g. a column's or a frame's
    weighted mean residual) has variance ``sigma^2 + noise``; ``sigma^2`` is estimated by
    moments over the entries ``has`` (default all) and every entry gets its best linear
    unbiased prediction ``mean sigma^2 / (sigma^2 + noise)`` (entries outside ``has``: 0).
    Returns ``(predictions, sigma, shrinkage factors)``; the factors sum to the effective number
    of parameters."""
    if has is None:
        has = torch.ones_like(mean, dtype=torch.bool)
    s2 = max(float(((mean**2 - noise)[has]).mean()), 0.0) if bool(has.any()) else 0.0
    shrink = torch.where(has, s2 / (s2 + noise), 0.0)
    return mean * shrink, math.sqrt(s2), shrink


def depth_residuals(obs, ctx, pred) -> tuple[torch.Tensor, torch.Tensor]:
    """The temporal means' depth residuals on the depth pixels and their weights ``n / sd^2``."""
    md = ctx.mask_d
    return (obs.m_d - pred.mu_d)[md], (obs.n / pred.sd_d**2)[md]


def r4(x) -> float:
    """``x`` rounded to 4 decimals, for the report."""
    return round(float(x), 4)


class ClosedFormMapTerm(Term):
    """A member with no scalar parameters: a map (``model.profiles[name]``, its effective degrees
    of freedom in ``model.values[name + ".dof"]``) estimated in closed form
    (:meth:`~Term.update_closed_form`) between the L-BFGS rounds. Subclasses set the class
    attributes and override :meth:`~Term.update_closed_form` and :meth:`~Term.describe`, and
    set ``gain_map_term`` or override :meth:`~Term.simulator_term`."""

    closed_form = True
    #: a map that is a gain: the simulator term that applies it (called with ``gain_map=``)
    gain_map_term: ClassVar[type | None] = None

    def simulator_term(self, v: dict, model):
        if self.gain_map_term is None:
            raise NotImplementedError(f"{self.name}: set gain_map_term or override simulator_term")
        g = model.profiles.get(self.name)
        return None if g is None else self.gain_map_term(gain_map=g)

    def initial_values(self, model, obs, ctx, pred) -> list[dict]:
        return [{}]

    def effective_parameters(self, values: dict) -> float:
        return float(values.get(f"{self.name}.dof", 0.0))
