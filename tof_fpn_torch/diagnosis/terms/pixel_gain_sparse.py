"""``pixel_gain`` on a share of the pixels only: weak or hot pixels, rows and clusters (a flexible
member of the ``pixel_gain`` effect).

The catalogue's gain is photo-response non-uniformity of every pixel, a Gaussian random effect of
rms ``g`` on each amplitude mean. A sensor's defects are often sparse instead: a few per cent of
its pixels (single pixels, clusters, a weak row) collect a few per cent less (or more) light, the
rest none. Spread over all pixels that is a tiny rms whose Gaussian cannot hold the defects' large
deviations. This member gives a share ``s`` of the pixels a gain of rms ``g`` and the others none:
each pixel's amplitude mean is a scale mixture

    (1 - s) N(m; mu, v_m) + s N(m; mu, v_m + (g mu)^2)

(``v_m``: the mean's variance without it; which pixels carry it is integrated out). Two
parameters. The signature is the catalogue gain's: the amplitude moves by a share of itself
(twice as much for a pixel twice as bright), the depth does not move, fine in space, the same in
every frame (:func:`~tof_fpn_torch.diagnosis.signature.fine_share` scales its gain). Not applied
together with the outlier mixture of ``impulsive_pixels`` (whose likelihood is frame by frame).
The report names it ``pixel_gain``.
"""

from __future__ import annotations

import torch

from ...sim import PixelGain
from ..params import ParamSpec
from ..signature import fine_share
from .base import Term, r4

__all__ = ["MAX_SPARSE_SHARE", "SPARSE_Z", "PixelGainSparseTerm"]

#: Largest share of the pixels the member's gain may sit on (beyond it, it is the catalogue's).
MAX_SPARSE_SHARE: float = 0.5
#: A pixel's amplitude mean this many sd from the prediction counts towards the starting share.
SPARSE_Z: float = 3.0


class PixelGainSparseTerm(Term):
    """The share ``s`` of the pixels with a gain and its rms ``g`` (relative); starts from the
    share and rms of the amplitude means beyond ``SPARSE_Z`` sd, and at (5 %, 2 %)."""

    name = "pixel_gain_sparse"
    signature = "pixel_gain"
    specs = (
        ParamSpec("pixel_gain_sparse.share", "logit", MAX_SPARSE_SHARE),
        ParamSpec("pixel_gain_sparse.rms", "log", 0.01),
    )
    enters = "variance"
    sim_name = "pixel_gain"
    axes = ("amp_mean|pixels",)
    about = "a gain on a share of the pixels only (weak or hot pixels, rows, clusters)"

    def simulator_term(self, v: dict, model):
        share = float(v["pixel_gain_sparse.share"])
        return PixelGain(float(v["pixel_gain_sparse.rms"]), share=max(share, 1e-9))

    def amplitude_sd_mixture(self, v: dict, mu_a):
        return v["pixel_gain_sparse.share"], v["pixel_gain_sparse.rms"] * mu_a

    def signature_share(self, obs, ctx, pred):
        """A gain per pixel: the share of the amplitude misfit finer than a smoothing."""
        return fine_share(obs, ctx, pred)

    def initial_values(self, model, obs, ctx, pred) -> list[dict]:
        starts = [{"pixel_gain_sparse.share": 0.05, "pixel_gain_sparse.rms": 0.02}]
        m = ctx.mask_a & torch.isfinite(obs.m_a) & (obs.n > 0)
        if int(m.sum()) < 16:
            return starts
        mu = pred.mu_a.detach()[m]
        tau = pred.tau_a.detach()[m] if isinstance(pred.tau_a, torch.Tensor) else pred.tau_a
        vm = pred.sd_a.detach()[m] ** 2 / obs.n[m] + tau**2
        rel = (obs.m_a[m] - mu) / mu.clamp_min(1e-12)
        far = (obs.m_a[m] - mu).abs() > SPARSE_Z * vm.sqrt()
        share = float(far.double().mean()) - 0.0027  # less the Gaussian's share beyond 3 sd
        if share > 1e-3:
            rms = float(rel[far].square().mean().sqrt())
            starts.append(
                {
                    "pixel_gain_sparse.share": min(share, 0.9 * MAX_SPARSE_SHARE),
                    "pixel_gain_sparse.rms": max(rms, 1e-4),
                }
            )
        return starts

    def describe(self, model, obs, pred) -> dict:
        v = model.values
        return {
            "share_of_pixels_percent": r4(v["pixel_gain_sparse.share"] * 100),
            "rms_percent": r4(v["pixel_gain_sparse.rms"] * 100),
        }
