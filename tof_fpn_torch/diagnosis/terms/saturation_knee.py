"""``saturation`` in the shape of the data: a soft compression of the raw samples over a knee
of free width (a flexible member of the ``saturation`` effect).

A sensor's limit is not always a hard full-well clip: an anti-blooming drain, a logarithmic
pixel or a non-linear ADC compress the bright samples gradually. This member compresses every
sample ``R`` (e-) by ``sim.optics.soft_limit`` (``level - knee softplus((level - R) / knee)``,
normalised to keep the dark samples as they are): ``R`` itself well below the level,
approaching a ceiling above it, the bend over about ``knee`` (two parameters;
a knee near 0 is the hard clip; the knee is at most ``KNEE_MAX_SHARE`` of the level: a knee as
wide as the level bends every sample, dark ones too, and scales every sample's noise by the
slope, a free scale of the noise law that fits any misfit of the spread, not a saturation).
The compression is deterministic on the mean samples and scales
each sample's shot and read noise by its slope. Its signature is
the effect's: the raw samples capped (an amplitude ceiling, a depth error growing towards it, the
affected share rising with reflectance and nearness); the report names it ``saturation``.
"""

from __future__ import annotations

from ...sim import Saturation
from ...sim.optics import soft_limit
from ..params import ParamSpec
from .base import Term, r4
from .saturation import START_QUANTILES, clipped_share, pile_description, start_levels

__all__ = ["KNEE_MAX_SHARE", "KNEE_SHARES", "SaturationKneeTerm"]

#: starting knees as shares of the starting level
KNEE_SHARES: tuple[float, ...] = (0.03, 0.15)
#: widest knee, as a share of the level (samples below half the level keep a slope of at least
#: ``sigmoid(0.5 / KNEE_MAX_SHARE)``, 0.88: their noise is not scaled away)
KNEE_MAX_SHARE: float = 0.25


class SaturationKneeTerm(Term):
    """The level (e-) the samples approach and the knee's width as a share of it."""

    name = "saturation_knee"
    signature = "saturation"
    specs = (
        ParamSpec("saturation_knee.level", "log", 1.0, "e-", charge=True),
        ParamSpec("saturation_knee.knee_share", "logit", KNEE_MAX_SHARE),
    )
    enters = "chain"
    sim_name = "saturation"
    axes = ("amp_mean|raw", "depth_mean|raw")
    about = "soft compression of the raw samples towards a level over a knee of free width"
    slow = True
    restarts_from_robust_values = True

    def simulator_term(self, v: dict, model):
        lv = v["saturation_knee.level"]
        return Saturation(lv, v["saturation_knee.knee_share"] * lv)

    def apply_mean(self, state, v: dict, model, chain):
        s = state.samples
        lv = v["saturation_knee.level"]
        var_e = s.clamp_min(0) + v["camera.read_noise"] ** 2
        prev = chain.sample_var if chain.sample_var is not None else var_e
        state.samples, slope = soft_limit(s, lv, v["saturation_knee.knee_share"] * lv)
        chain.sample_var = prev * slope * slope
        return state

    def initial_values(self, model, obs, ctx, pred) -> list[dict]:
        # the clip's starting levels (every third), each with a narrow and a wide knee
        return [
            {"saturation_knee.level": lv, "saturation_knee.knee_share": share}
            for lv in start_levels(model, obs, ctx, pred, START_QUANTILES[::3])
            for share in KNEE_SHARES
        ]

    def describe(self, model, obs, pred) -> dict:
        v = model.values
        g = v["camera.conversion_gain"]
        lv = v["saturation_knee.level"]
        return {
            "level_e": r4(lv),
            "knee_e": r4(v["saturation_knee.knee_share"] * lv),
            "level_amplitude_units": r4(lv / g),
            # the share of pixels whose largest sample passes the level (a hard clip's share)
            "share_of_pixels_clipped": r4(clipped_share(model, obs, self.name, lv)),
            **pile_description(obs),
        }
