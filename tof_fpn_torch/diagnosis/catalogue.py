"""The catalogue of candidate physics: the vocabulary, the fitted parameters of each term and how
each enters the model.

How a term enters (``Effect.enters``):

* ``chain`` -- a deterministic simulator term in the noise-free chain whose decoded depth and
  amplitude are the model's means (``cyclic_error``, ``amplitude_bias``, ``vignetting``,
  ``flying_pixels``, ``saturation``, ``multipath``; ``fpn_pattern`` too, its profiles estimated in
  closed form);
* ``variance`` -- a change of the predicted spread (``noise_floor``: clock jitter adds its
  variance to every depth; ``pixel_gain``: a random gain per pixel adds ``(rms A)^2`` to the
  variance of the amplitude's temporal mean, the EMVA 1288 PRNU);
* ``frames`` -- per-frame changes (``temporal_drift``) and per-frame outliers
  (``impulsive_pixels``: a mixture with a uniform component);
* ``wrap`` -- ``phase_wrapping``: the depth is folded into ``[0, R)``.

``multipath`` is diffuse interreflection (:class:`~tof_fpn_torch.sim.Multipath`): the relay
within the visible scene from its back-projected geometry (field of view and near-field length
profiled on a grid, its efficiency fitted) plus a uniform relay of the scene-mean return (Fuchs
2010 without geometry) for light from outside the view.
"""

from __future__ import annotations

from dataclasses import dataclass

from .. import constants as K
from ..sim import (
    AmplitudeBias,
    CyclicError,
    FPNPattern,
    ImpulsivePixels,
    LensBlur,
    Multipath,
    PhaseJitter,
    PixelGain,
    Saturation,
    TemporalDrift,
    Vignetting,
)
from .params import ParamSpec

__all__ = [
    "CATALOGUE",
    "REVEALED_WITHOUT_SCENE",
    "VOCABULARY",
    "Effect",
    "build_term",
    "harmonics",
    "implemented",
]

#: every name the report may use (``none`` when nothing is significant)
VOCABULARY: tuple[str, ...] = (
    "cyclic_error",
    "amplitude_bias",
    "fpn_pattern",
    "pixel_gain",
    "noise_floor",
    "impulsive_pixels",
    "saturation",
    "vignetting",
    "temporal_drift",
    "multipath",
    "flying_pixels",
    "phase_wrapping",
)


@dataclass(frozen=True)
class Effect:
    """A catalogue entry: ``name``, its fitted ``specs``, how it ``enters`` the model, the
    simulator term name (``term``), the located statistics that point at it (``axes``) and
    what it is (``about``)."""

    name: str
    specs: tuple[ParamSpec, ...]
    enters: str
    term: str | None
    axes: tuple[str, ...]
    about: str
    implemented: bool = True


def harmonics(n_phases: int) -> tuple[int, int]:
    """The correlation harmonics that alias into the first DFT bin of N samples: N - 1, N + 1."""
    return (n_phases - 1, n_phases + 1)


def _cyclic_specs() -> tuple[ParamSpec, ...]:
    return tuple(
        ParamSpec(f"cyclic_error.{p}{i}", "lin", K.DIAG_SCALE_CYCLIC)
        for i in (1, 2)
        for p in ("cos", "sin")
    )


CATALOGUE: dict[str, Effect] = {
    e.name: e
    for e in (
        Effect(
            "cyclic_error",
            _cyclic_specs(),
            "chain",
            "cyclic_error",
            ("depth_mean|depth_mod", "depth_mean|depth"),
            "non-sinusoidal correlation: harmonics N-1 and N+1 alias into the phase",
        ),
        Effect(
            "amplitude_bias",
            (
                ParamSpec("amplitude_bias.delay", "lin", K.DIAG_SCALE_DEPTH, "m"),
                ParamSpec("amplitude_bias.reference", "log", 1.0, "e-"),
            ),
            "chain",
            "amplitude_bias",
            ("depth_mean|amplitude",),
            "signal-dependent delay b A_ref / (A + A_ref)",
        ),
        Effect(
            "fpn_pattern",
            (),
            "chain",
            "fpn_pattern",
            ("depth_mean|column", "depth_mean|row"),
            "column / row delays of any spectrum (profiles estimated in closed form)",
        ),
        Effect(
            "vignetting",
            (
                ParamSpec("vignetting.quadratic", "lin", 0.1),
                ParamSpec("vignetting.quartic", "lin", 0.1),
                ParamSpec("vignetting.centre_x", "lin", 10.0, "px"),
                ParamSpec("vignetting.centre_y", "lin", 10.0, "px"),
            ),
            "chain",
            "vignetting",
            ("amp_mean|radius",),
            "lens fall-off 1 + a2 r^2 + a4 r^4 about a fitted centre",
        ),
        Effect(
            "temporal_drift",
            (
                ParamSpec("temporal_drift.depth_step", "lin", K.DIAG_SCALE_DEPTH, "m"),
                ParamSpec("temporal_drift.amplitude_step", "lin", 0.01),
                ParamSpec("temporal_drift.time_constant", "log", 1.0, "s"),
            ),
            "frames",
            "temporal_drift",
            ("depth_frame|frame", "amp_frame|frame"),
            "warm-up: delay D (1 - exp(-t/tau)), light 1 + a (1 - exp(-t/tau))",
        ),
        Effect(
            "noise_floor",
            (ParamSpec("noise_floor.sigma", "rootabs", K.DIAG_SCALE_DEPTH**2, "m"),),
            "variance",
            "noise_floor",
            ("depth_spread|amplitude", "depth_mean|pixels"),
            "clock jitter: a depth noise floor that does not fall with amplitude",
        ),
        Effect(
            "pixel_gain",
            (ParamSpec("pixel_gain.rms", "rootabs", K.DIAG_SCALE_CYCLIC**2),),
            "variance",
            "pixel_gain",
            ("amp_mean|pixels",),
            "photo-response non-uniformity (PRNU), a random gain per pixel",
        ),
        Effect(
            "impulsive_pixels",
            (ParamSpec("impulsive_pixels.rate", "logit", K.DIAG_MAX_IMPULSIVE_RATE),),
            "frames",
            "impulsive",
            ("depth_tail|pixels", "depth_spread|pixels"),
            "frame-pixels with no information: a uniform component of the mixture",
        ),
        Effect(
            "saturation",
            (ParamSpec("saturation.level", "log", 1.0, "e-"),),
            "chain",
            "saturation",
            ("amp_mean|raw", "depth_mean|raw"),
            "full-well clip of the noisy correlation samples (mean and variance of the clip of "
            "each sample's shot and read noise)",
        ),
        Effect(
            "flying_pixels",
            (ParamSpec("flying_pixels.sigma", "log", 1.0, "px"),),
            "chain",
            "flying_pixels",
            ("depth_mean|edge",),
            "Gaussian PSF mixing the returns of neighbouring pixels at depth edges",
        ),
        Effect(
            "phase_wrapping",
            (ParamSpec("phase_wrapping.range", "log", 1.0, "m"),),
            "wrap",
            None,
            ("depth_mean|depth",),
            "depth folded into the unambiguous range [0, R)",
        ),
        Effect(
            "multipath",
            (
                ParamSpec("multipath.strength", "abs", K.DIAG_SCALE_CYCLIC),
                ParamSpec("multipath.extra_path", "abs", 1.0, "m"),
                ParamSpec("multipath.scene_relay", "abs", K.DIAG_SCALE_CYCLIC),
            ),
            "chain",
            "multipath",
            ("depth_mean|amplitude", "depth_mean|depth", "amp_mean|amplitude"),
            "diffuse interreflection: light relayed within the visible scene (its 3-D geometry, "
            "inverse square, own paths) plus a uniform relay of the scene-mean return from "
            "outside the view, each reflected with the pixel's albedo",
        ),
    )
}


#: What a recording can reveal when its scene is estimated from the recording itself: structure
#: finer than the smoothing and changes over time. The amplitude of every pixel then carries its
#: own reflectance, so the baseline gets ``pixel_gain`` as a per-pixel amplitude texture (PRNU and
#: reflectance texture cannot be told apart without a scene).
REVEALED_WITHOUT_SCENE: tuple[str, ...] = (
    "fpn_pattern",
    "noise_floor",
    "impulsive_pixels",
    "temporal_drift",
)


def implemented() -> list[str]:
    """Names of the catalogue terms the diagnosis can fit."""
    return [n for n, e in CATALOGUE.items() if e.implemented]


def build_term(name: str, v: dict, model, *, for_chain: bool):
    """The simulator term of catalogue entry ``name`` with values ``v`` (floats or tensors).

    ``for_chain``: only the deterministic terms of the noise-free mean chain (None otherwise)."""
    n = model.camera.n_phases
    if name == "cyclic_error":
        return CyclicError(
            harmonics=harmonics(n),
            cos_terms=(v["cyclic_error.cos1"], v["cyclic_error.cos2"]),
            sin_terms=(v["cyclic_error.sin1"], v["cyclic_error.sin2"]),
        )
    if name == "amplitude_bias":
        return AmplitudeBias(v["amplitude_bias.delay"], v["amplitude_bias.reference"])
    if name == "fpn_pattern":
        return FPNPattern(
            column_profile=model.profiles.get("columns"), row_profile=model.profiles.get("rows")
        )
    if name == "vignetting":
        return Vignetting(
            v["vignetting.quadratic"],
            v["vignetting.quartic"],
            v["vignetting.centre_x"],
            v["vignetting.centre_y"],
        )
    if name == "flying_pixels":
        return LensBlur(v["flying_pixels.sigma"])
    if name == "saturation":
        return Saturation(v["saturation.level"])
    if name == "multipath":
        return Multipath(
            v["multipath.strength"],
            v["multipath.extra_path"],
            scene_relay=v.get("multipath.scene_relay", 0.0),
            field_of_view=v.get("multipath.field_of_view", K.MULTIPATH_FIELD_OF_VIEW_DEG),
            near_field=v.get("multipath.near_field", K.MULTIPATH_NEAR_FIELD_M),
        )
    if for_chain:
        return None
    if name == "temporal_drift":
        return TemporalDrift(
            v["temporal_drift.depth_step"],
            v["temporal_drift.amplitude_step"],
            v["temporal_drift.time_constant"],
            model.frame_interval,
        )
    if name == "noise_floor":
        return PhaseJitter(v["noise_floor.sigma"])
    if name == "pixel_gain":
        return PixelGain(v["pixel_gain.rms"])
    if name == "impulsive_pixels":
        return ImpulsivePixels(
            rate=float(v["impulsive_pixels.rate"]), level=model.impulsive_level, mode="uniform"
        )
    return None
