"""``saturation``: the full-well clip of the noisy correlation samples.

The camera clips each noisy sample, so the model's mean chain takes the mean and variance of the
clip of each sample's shot and read noise (its mean bends over about one sd; the clipped part has
no noise), and the depth and amplitude noise come from those unequal variances. A pixel whose
samples are all clipped has no phase: its depth spread is at most that of a uniform over the
range. The level's gradient is zero unless the clip touches some samples, so the starts are a
dense grid of high quantiles of the largest raw sample (docs/diagnosis.md). When the recording
holds the raw samples, a clip leaves direct evidence: samples piled up at one value (the ADC's
top code, a common full well) or each pixel's largest sample repeated over its frames (a full
well of its own); those levels are starts too, and the report states the piles.
"""

from __future__ import annotations

import math

import torch

from ... import constants as K
from ...sim import Saturation
from ..params import ParamSpec
from ..prediction import predict
from .base import Term, r4

__all__ = [
    "PILE_CODES",
    "PILE_FACTOR",
    "PILE_MIN",
    "START_QUANTILES",
    "SaturationTerm",
    "clipped_share",
    "peak_samples",
    "raw_piles",
    "start_levels",
]

#: Quantiles of the largest raw sample (predicted, and implied by the observed amplitude) at
#: which the level starts: a dense grid from the median to the 99.9th percentile, as a clip of
#: many pixels predicts them to a fraction of their noise and the likelihood is sharp in the level.
START_QUANTILES: tuple[float, ...] = tuple(1 - 0.5 * 0.002 ** (k / 23) for k in range(24))


#: A clip leaves its samples at one raw value: a pixel's largest raw sample repeated at least
#: this many times over its frames and phases is piled up ...
PILE_MIN: int = 3
#: ... and at least twice the samples on the ``PILE_CODES`` codes just below it; a level
#: common to all pixels holds a pile when it holds at least ``PILE_FACTOR`` times the samples
#: of an average code of the 32 codes below it
PILE_CODES: int = 3
PILE_FACTOR: float = 20.0


def raw_piles(obs) -> dict | None:
    """The direct evidence of a clip in the raw samples (None without them): ``level`` (stored
    units) where the most samples pile up at the top of the range (the recording's largest
    sample when it holds a pile, else None), its ``share`` of the samples, and the pixels whose
    own largest sample repeats :data:`PILE_MIN` times or more and twice as often as the
    samples on the :data:`PILE_CODES` codes below it (``pixel_share``; their levels'
    ``pixel_levels``: quartiles), e.g. a full well of each pixel's own."""
    raw = getattr(obs, "raw", None)
    if raw is None or raw.dim() != 4:
        return None
    x = raw.to(torch.float64)
    fin = torch.isfinite(x)
    if not bool(fin.any()):
        return None
    top = float(x[fin].max())
    n_top = int((x == top).sum())
    below = int(((x < top) & (x >= top - 32)).sum()) / 32.0
    level = top if n_top >= PILE_MIN and n_top >= PILE_FACTOR * max(below, 1.0) else None
    per = torch.where(fin, x, -math.inf).flatten(0, 1)  # (T N, H, W)
    peak = per.amax(0)
    reps = (per == peak.unsqueeze(0)).sum(0)
    # below a clip the samples spread over many codes; noise alone puts at least as many
    # samples on the few codes just below a pixel's largest as on that largest itself
    near = ((per < peak.unsqueeze(0)) & (per >= peak.unsqueeze(0) - PILE_CODES)).sum(0)
    piled = (reps >= PILE_MIN) & (reps >= 2 * near) & torch.isfinite(peak) & (peak > 0)
    out = {
        "level": level,
        "share": n_top / max(int(fin.sum()), 1) if level is not None else 0.0,
        "pixel_share": float(piled.double().mean()),
        "pixel_levels": [],
    }
    if bool(piled.any()):
        lv = peak[piled]
        out["pixel_levels"] = [float(torch.quantile(lv, q)) for q in (0.25, 0.5, 0.75)]
    return out


def peak_samples(model, p, depth: torch.Tensor, amp: torch.Tensor):
    """The largest of the N raw samples (DN) of pixels with ``depth`` (m) and amplitude ``amp``
    (DN) on the predicted offset: ``offset + A max_n cos(phi + 2 pi n / N)``."""
    n = model.camera.n_phases
    phi = depth * (4 * math.pi * float(model.camera.modulation_frequency) / K.SPEED_OF_LIGHT_AIR)
    th = torch.arange(n, dtype=torch.float64) * (2 * math.pi / n)
    cmax = torch.cos(phi.unsqueeze(-1) + th).amax(-1)
    return p.offset + amp * cmax


def start_levels(model, obs, ctx, pred, quantiles=START_QUANTILES) -> list[float]:
    """Starting levels (e-) of a clip: the clip must touch some samples at the start, or the
    level's gradient is zero. The ``quantiles`` of the largest predicted raw sample and of the
    largest sample that the observed amplitude and depth imply (a clipped pixel reads a smaller
    amplitude)."""
    g = model.values["camera.conversion_gain"]
    out = []
    piles = raw_piles(obs)
    if piles is not None:
        # the raw samples show where they clip: those levels first (the offset of the stored
        # samples is the model's, so a raw level is a level of the samples in DN)
        out += [piles["level"] * g] if piles["level"] is not None else []
        out += [lv * g for lv in piles["pixel_levels"]]
    for peaks in (
        peak_samples(model, pred, pred.mu_d, pred.a0),
        peak_samples(model, pred, obs.m_d, obs.m_a),
    ):
        pk = (peaks * g)[ctx.mask_a & torch.isfinite(peaks)]
        if pk.numel():
            out += [float(torch.quantile(pk, q)) for q in quantiles]
    return out


class SaturationTerm(Term):
    """The full-well level (e-)."""

    name = "saturation"
    specs = (ParamSpec("saturation.level", "log", 1.0, "e-", charge=True),)
    enters = "chain"
    sim_name = "saturation"
    axes = ("amp_mean|raw", "depth_mean|raw")
    about = (
        "full-well clip of the noisy correlation samples (mean and variance of the clip of "
        "each sample's shot and read noise)"
    )
    slow = True
    restarts_from_robust_values = True

    def simulator_term(self, v: dict, model):
        return Saturation(v["saturation.level"])

    def apply_mean(self, state, v: dict, model, chain):
        t = self.simulator_term(v, model)
        var_e = state.samples.clamp_min(0) + v["camera.read_noise"] ** 2
        state.samples, chain.sample_var = t.noisy_moments(state.samples, var_e)
        return state

    def depth_variance_limit(self, r_cam: float):
        return r_cam**2 / 12.0

    def initial_values(self, model, obs, ctx, pred) -> list[dict]:
        return [{"saturation.level": lv} for lv in start_levels(model, obs, ctx, pred)]

    def clip_level(self, v: dict):
        return v["saturation.level"] / v["camera.conversion_gain"]

    def baseline_stated(self, obs, model):
        if obs.clip_level is None:
            return None
        g = model.values["camera.conversion_gain"]
        note = (
            f"the recording states its camera's clip level ({obs.clip_level:g} "
            f"{obs.amplitude_unit}: full well or ADC top code): the baseline clips the raw "
            "samples there (saturation at that level is the camera's own, not a finding)"
        )
        return {"saturation.level": obs.clip_level * g}, note

    def describe(self, model, obs, pred) -> dict:
        v = model.values
        lv = v["saturation.level"]
        out = {
            "level_e": r4(lv),
            "level_amplitude_units": r4(lv / v["camera.conversion_gain"]),
            "share_of_pixels_clipped": r4(clipped_share(model, obs, self.name, lv)),
        }
        out.update(pile_description(obs))
        return out


def pile_description(obs) -> dict:
    """What the raw samples show of a clip, for the report (empty without raw samples)."""
    piles = raw_piles(obs)
    if piles is None:
        return {}
    out = {
        "raw_share_of_pixels_piled_at_their_top": r4(piles["pixel_share"]),
        "raw_share_of_samples_at_the_top_level": r4(piles["share"]),
    }
    if piles["level"] is not None:
        out["raw_pile_level"] = r4(piles["level"])
    return out


def clipped_share(model, obs, name: str, level: float) -> float:
    """The chance that a pixel's largest raw sample, with its shot and read noise, passes
    ``level`` (e-) in a frame, averaged over the pixels; the samples as the model predicts them
    without its term ``name``."""
    v = model.values
    with torch.no_grad():
        p0 = predict(model.without(name), obs)
    peak = peak_samples(model, p0, p0.mu_d, p0.a0)[obs.known] * v["camera.conversion_gain"]
    sd = torch.sqrt(peak.clamp_min(0) + v["camera.read_noise"] ** 2)
    return float(torch.special.ndtr((peak - level) / sd).double().mean())
