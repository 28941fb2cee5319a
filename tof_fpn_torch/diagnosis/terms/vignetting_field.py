"""``vignetting`` of any shape: a relative illumination that falls along every ray from the
frame centre, free in angle and radius (a flexible member of the ``vignetting`` effect).

The catalogue's ``1 + a2 r^2 + a4 r^4`` is a round lens. An anamorphic or tilted lens darkens
an ellipse, a lens hood or a filter ring one corner, a sensor's microlenses the edges of one
axis more than the other. What they share is the signature: light lost towards the edge of the
field, more the further out along each ray from the centre, the same share for dark and bright
pixels of one place, no change of the depth. This member fits that: the loss
``s(x, y) = -ln g >= 0`` is a sum of non-negative weights times basis functions that rise
along every ray, ``RAMPS`` radial ramps ``((r - t) / (1 - t))_+^2`` (``r`` in half-diagonals
from the frame centre) times ``SECTORS`` triangular hat functions of the angle (a partition of
one), so that any non-negative weights give a loss that never falls outwards. The weights are
the non-negative least-squares fit, in closed form, of the log ratio of the predicted (without
the member) to the observed mean amplitude, weighted by the inverse variance of that log; the
scale of all the light is fitted with them (two more columns, up and down; it goes into the
responsivity). The positive weights count as parameters. The report names it ``vignetting``.
"""

from __future__ import annotations

import math

import torch

from ...sim import Vignetting
from ..nnls import nnls
from ..prediction import predict
from .base import ClosedFormMapTerm, r4

__all__ = ["RAMPS", "SECTORS", "VignettingFieldTerm", "loss_basis"]

#: where the radial ramps start (half-diagonals from the frame centre)
RAMPS: tuple[float, ...] = (0.0, 0.2, 0.4, 0.6, 0.8)
#: triangular hat functions of the angle about the frame centre
SECTORS: int = 8
_KEY = "vignetting_field"


def loss_basis(h: int, w: int, yx: torch.Tensor | None = None) -> torch.Tensor:
    """The (RAMPS x SECTORS, H, W) basis of the loss ``-ln g``: each rises (weakly) along every
    ray from the frame centre; any non-negative combination does too. ``yx`` (2, ...): the
    basis at these (row, column) positions instead of the pixels (then (K, ...))."""
    if yx is None:
        yy = torch.arange(h, dtype=torch.float64).view(h, 1).expand(h, w)
        xx = torch.arange(w, dtype=torch.float64).view(1, w).expand(h, w)
        yx = torch.stack([yy, xx])
    yy, xx = yx[0] - (h - 1) / 2.0, yx[1] - (w - 1) / 2.0
    half_diag = max(math.hypot((h - 1) / 2.0, (w - 1) / 2.0), 1e-9)
    r = torch.sqrt(xx * xx + yy * yy) / half_diag
    u = (torch.atan2(yy, xx) % (2 * math.pi)) / (2 * math.pi / SECTORS)  # in sector widths
    hats = []
    for j in range(SECTORS):
        dist = torch.remainder(u - j + SECTORS / 2.0, float(SECTORS)) - SECTORS / 2.0
        hats.append((1.0 - dist.abs()).clamp_min(0.0))
    out = [((r - t).clamp_min(0.0) / (1.0 - t)) ** 2 * hat for t in RAMPS for hat in hats]
    return torch.stack(out)


def update_field(model, obs, ctx, pred, sel: str = "all"):
    """``model`` with the loss weights (and the light's scale) fitted in closed form on the
    ``sel`` pixels against the model without the member (module docstring)."""
    h, w = obs.shape
    with torch.no_grad():
        bare = predict(model.without(_KEY), obs, scene=ctx.scene)
        ok = ctx.mask_a & ctx.select(sel) & (obs.m_a > 0) & (bare.mu_a > 0) & (obs.n > 0)
        y = torch.log(bare.mu_a[ok] / obs.m_a[ok])
        var = bare.sd_a[ok] ** 2 / obs.n[ok] + (
            bare.tau_a[ok] ** 2 if isinstance(bare.tau_a, torch.Tensor) else bare.tau_a**2
        )
        wt = (bare.mu_a[ok] ** 2 / var.clamp_min(1e-300)).to(torch.float64)
        basis = loss_basis(h, w)
        cols = basis[:, ok]
        one = torch.ones_like(y).view(1, -1)
        a = torch.cat([cols, one, -one])
        aw = a * wt
        x = nnls((aw @ a.T).numpy(), (aw @ y.to(torch.float64)).numpy())
    out = model.copy()
    weights = torch.from_numpy(x[:-2])
    loss = torch.einsum("k,khw->hw", weights, basis)
    out.profiles[_KEY] = torch.exp(-loss)
    out.values[f"{_KEY}.dof"] = float((weights > 0).sum())
    # the light's scale fitted with the weights: into the responsivity (the L-BFGS refines it)
    out.values["photons.responsivity"] = model.values["photons.responsivity"] * math.exp(
        -float(x[-2] - x[-1])
    )
    return out


class VignettingFieldTerm(ClosedFormMapTerm):
    """No scalar parameters: the relative illumination (``model.profiles["vignetting_field"]``)
    is estimated in closed form (:func:`update_field`)."""

    name = "vignetting_field"
    signature = "vignetting"
    enters = "chain"
    sim_name = "vignetting"
    axes = ("amp_mean|radius",)
    about = "light lost towards the edge along every ray from the centre, free in angle"
    profile_keys = (_KEY,)
    gain_map_term = Vignetting

    def update_closed_form(self, model, obs, ctx, pred, sel: str):
        return update_field(model, obs, ctx, pred, sel)

    def describe(self, model, obs, pred) -> dict:
        g = model.profiles.get(_KEY)
        if g is None:
            return {"effective_parameters": 0.0}
        corners = g[[0, 0, -1, -1], [0, -1, 0, -1]]
        return {
            "corners_relative_illumination_percent": [r4(100 * float(c)) for c in corners],
            "least_relative_illumination_percent": r4(100 * float(g.min())),
            "effective_parameters": r4(model.values.get(f"{_KEY}.dof", 0.0)),
        }
