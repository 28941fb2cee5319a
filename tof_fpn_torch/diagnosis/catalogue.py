"""The catalogue of candidate physics: every term the diagnosis can name, one class each.

Each term is a subclass of :class:`~tof_fpn_torch.diagnosis.terms.base.Term` in its own module
``tof_fpn_torch/diagnosis/terms/<name>.py`` and holds everything about it: its fitted parameters
(``specs``), the located statistics that point at it (``axes``), its starting values, how it
enters the model's prediction, its description for the report and its simulator term. The
shared machinery (prediction, likelihood, fit, ranking, report) asks the terms of a model through
the hooks of ``Term`` and never by name. :data:`TERMS` below is the one place they are
registered; its order is the order the candidates are tried in (and breaks ties of equal scores).

How a term enters (``Term.enters``):

* ``chain`` -- a deterministic simulator term in the noise-free chain whose decoded depth and
  amplitude are the model's means (``cyclic_error``, ``amplitude_bias``, ``vignetting``,
  ``flying_pixels``, ``saturation``, ``multipath``; ``fpn_pattern`` too, its profiles estimated in
  closed form);
* ``variance`` -- a change of the predicted spread (``noise_floor``: clock jitter adds its
  variance to every depth; ``pixel_gain``: a random gain per pixel adds ``(rms A)^2`` to the
  variance of the amplitude's temporal mean, the EMVA 1288 PRNU);
* ``frames`` -- per-frame changes (``temporal_drift``), per-frame outliers
  (``impulsive_pixels``: a mixture with a uniform component) and a heavy-tailed law of the
  readings (``noise_floor_tails``: Student-t);
* ``wrap`` -- ``phase_wrapping``: the depth is folded into ``[0, R)``.

Adding a term
-------------

1. Write ``tof_fpn_torch/diagnosis/terms/<name>.py`` with one subclass of ``Term``; the module's
   file name is the term's ``name``. Set the class attributes ``name``, ``specs`` (one
   :class:`~tof_fpn_torch.diagnosis.params.ParamSpec` per fitted scalar, keys
   ``"<name>.<field>"``; ``charge=True`` for a value in e-), ``enters`` (a key of
   ``terms.base.ENTERS``), ``sim_name`` (its simulator term's name in ``sim.STAGE``, or None),
   ``axes`` (the ``channel|axis`` statistics it explains) and ``about`` (one line); and the
   flags that apply (``revealed_without_scene``, ``slow``, ``closed_form``, ...).
2. Implement ``simulator_term(v, model)`` (the ``sim`` term with values ``v``),
   ``initial_values(model, obs, ctx, pred)`` (a short list of starting dicts over its keys: a
   small grid of the non-linear parameters, closed-form least squares on the current residuals
   for the linear ones) and ``describe(model, obs, pred)`` (its fitted values in physical units
   for ``report.json``).
3. Implement the hook of how it enters: a ``chain`` term gets ``apply_mean`` for free from its
   simulator term; a ``variance`` term overrides ``depth_variance``, ``depth_variance_limit`` or
   ``amplitude_sd``; a ``frames`` term ``frame_means``, ``outlier_rate`` or ``depth_tail``; a ``wrap`` term
   ``wrap_range``. Tuning numbers of the term go at the top of its module, documented.
4. Register an instance in :data:`TERMS` below (at the end unless the order of candidates
   matters).
5. Test it: ``tests/test_diagnosis_terms.py`` checks every registered term against the whole
   interface (attributes, starting values, prediction, description, simulator term) on a small
   recording, and that no term is defined or registered elsewhere; add a test in
   ``tests/test_diagnosis_terms.py`` (or a file of its own) that plants the effect with the
   simulator and checks that the diagnosis names it and recovers its size (the planted-effect
   tests in ``tests/test_diagnosis.py`` show how).
"""

from __future__ import annotations

from .terms.amplitude_bias import AmplitudeBiasTerm
from .terms.amplitude_bias_shape import AmplitudeBiasShapeTerm
from .terms.base import Term
from .terms.cyclic_error import CyclicErrorTerm
from .terms.cyclic_error_series import CyclicErrorSeriesTerm
from .terms.flying_pixels import FlyingPixelsTerm
from .terms.fpn_pattern import FPNPatternTerm
from .terms.fpn_pixel_delays import FPNPixelDelaysTerm
from .terms.fpn_pixel_offsets import FPNPixelOffsetsTerm
from .terms.impulsive_pixels import ImpulsivePixelsTerm
from .terms.mixed_pixels import MixedPixelsTerm
from .terms.multipath import MultipathTerm
from .terms.multipath_sources import MultipathSourcesTerm
from .terms.noise_floor import NoiseFloorTerm
from .terms.noise_floor_tails import NoiseFloorTailsTerm
from .terms.phase_wrapping import PhaseWrappingTerm
from .terms.pixel_gain import PixelGainTerm
from .terms.pixel_gain_rows import PixelGainRowsTerm
from .terms.saturation import SaturationTerm
from .terms.saturation_knee import SaturationKneeTerm
from .terms.temporal_drift import TemporalDriftTerm
from .terms.temporal_drift_frames import TemporalDriftFramesTerm
from .terms.vignetting import VignettingTerm
from .terms.vignetting_field import VignettingFieldTerm

__all__ = [
    "CATALOGUE",
    "REVEALED_WITHOUT_SCENE",
    "TERMS",
    "VOCABULARY",
    "Term",
    "implemented",
]

#: every term, in the order the candidates are tried
TERMS: tuple[Term, ...] = (
    CyclicErrorTerm(),
    AmplitudeBiasTerm(),
    FPNPatternTerm(),
    VignettingTerm(),
    TemporalDriftTerm(),
    NoiseFloorTerm(),
    PixelGainTerm(),
    ImpulsivePixelsTerm(),
    SaturationTerm(),
    FlyingPixelsTerm(),
    PhaseWrappingTerm(),
    MultipathTerm(),
    AmplitudeBiasShapeTerm(),
    FPNPixelOffsetsTerm(),
    MixedPixelsTerm(),
    CyclicErrorSeriesTerm(),
    TemporalDriftFramesTerm(),
    SaturationKneeTerm(),
    MultipathSourcesTerm(),
    NoiseFloorTailsTerm(),
    VignettingFieldTerm(),
    PixelGainRowsTerm(),
    FPNPixelDelaysTerm(),
)

#: name -> term
CATALOGUE: dict[str, Term] = {t.name: t for t in TERMS}

#: every name the report may use (``none`` when nothing is significant): the effects, each
#: modelled by one or more terms (its physical form and flexible members, ``Term.signature``)
VOCABULARY: tuple[str, ...] = tuple(dict.fromkeys(t.effect for t in TERMS))

#: What a recording can reveal when its scene is estimated from the recording itself: structure
#: finer than the smoothing and changes over time (``Term.revealed_without_scene``).
REVEALED_WITHOUT_SCENE: tuple[str, ...] = tuple(t.name for t in TERMS if t.revealed_without_scene)


def implemented() -> list[str]:
    """Names of the catalogue terms the diagnosis can fit."""
    return [t.name for t in TERMS if t.implemented]
