"""``flying_pixels`` with a free share: pixels on depth edges that mix their own return with the
neighbouring surface's in any proportion (a flexible member of the ``flying_pixels`` effect).

A mixed pixel's footprint covers part of the other surface; how much varies from pixel to pixel
(the edge's sub-pixel position, the lens, the sensor's fill factor), so no point-spread function
predicts it. Its signature: it lies on a depth edge of the scene and its reading lies **between**
the two surfaces (its phasor is ``(1 - s) z_p + s z_q``), with the amplitude of that mixture,
and it is the same in every frame; an impulsive pixel lies anywhere, reads any value and changes
from frame to frame. The model: each pixel on an edge (a 4-neighbour's scene depth differs by
more than :data:`~tof_fpn_torch.sim.optics.EDGE_STEP_M`) is mixed with probability ``p`` (fitted),
its share uniform in (0, 1) and integrated out of the likelihood of its temporal mean
(:func:`~tof_fpn_torch.diagnosis.likelihood.nll`). One parameter. The report names it
``flying_pixels``.
"""

from __future__ import annotations

import torch

from ...sim import EdgeMixing, edge_partners
from ..params import ParamSpec
from .base import Term, r4

__all__ = ["MixedPixelsTerm"]


class MixedPixelsTerm(Term):
    """The probability ``p`` that an edge pixel is mixed; starts at 0.05, 0.2 and 0.6."""

    name = "mixed_pixels"
    signature = "flying_pixels"
    specs = (ParamSpec("mixed_pixels.probability", "logit", 1.0),)
    enters = "mixture"
    sim_name = "edge_mixing"
    axes = ("depth_mean|edge", "amp_mean|edge")
    about = "pixels on depth edges mixing both surfaces' returns with a free share"

    def simulator_term(self, v: dict, model):
        return EdgeMixing(probability=float(v["mixed_pixels.probability"]))

    def edge_mixture(self, v: dict):
        return v["mixed_pixels.probability"]

    def region(self, obs):
        return edge_partners(obs.scene_depth.to(torch.float64)) >= 0

    def initial_values(self, model, obs, ctx, pred) -> list[dict]:
        return [{"mixed_pixels.probability": p} for p in (0.05, 0.2, 0.6)]

    def describe(self, model, obs, pred) -> dict:
        return {"mixed_share_of_edge_pixels": r4(model.values["mixed_pixels.probability"])}
