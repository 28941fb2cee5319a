"""Signature shares: how much of the current misfit has the signature of a term that enters as a
spread (a variance or an outlier mixture) rather than as a structure.

A spread term fits any misfit: a random gain per pixel widens every amplitude mean until a
smooth misfit of another effect (a second bounce the model does not hold yet) costs little; an
outlier mixture takes the pixels of any gross misfit. What tells them from that misfit is where
it lives, not how large it is:

* **fine in space** (:func:`fine_share`; ``pixel_gain`` on the amplitude residuals,
  ``fpn_pixel_offsets`` on the phasor's residuals): a per-pixel gain or offset varies from
  pixel to pixel (a column pattern from column to column); the share of the excess variance of
  the residuals left after a smoothing of ``FINE_SCALE_PX`` px (within the scene's depth
  layers, so that a depth edge is not taken for fine structure) over the excess variance of the
  residuals themselves, in DN and relative to the amplitude (the smaller: the scene's amplitude
  texture is not the misfit's);
* **sporadic in time or isolated in space** (:func:`sporadic_share`, ``impulsive_pixels``):
  impulsive frame-pixels come and go; the share of the frame-pixels beyond ``OUTLIER_Z`` sd
  that sit on pixels beyond it in at most half the frames (a misfit fixed in time is beyond it
  in every frame), or on defect pixels (:func:`defect_pixels`). A defect pixel -- a hot pixel
  with the dark current of a crystal defect in a tap (EMVA 1288, defect pixels) -- is fixed in
  time, but it is rare, independent of its neighbours and of the scene, and far off: its
  temporal mean lies beyond ``OUTLIER_Z`` times the robust spread of all the pixels' means
  (a dense read-out pattern's Gaussian spread sets that scale; a hot pixel's dark charge of
  thousands of electrons is far outside it), and no neighbour is one (a depth edge's mixed
  pixels, a clipped highlight or a bright patch of multipath are runs of neighbours, never a
  lone pixel). Such pixels are the outliers of the mixture, not a random offset of every
  pixel: ``fpn_pixel_offsets`` (:func:`dense_share`) is credited with the excess of the
  means' spread that the defect pixels do not carry;
* **common to a frame** (:func:`common_share`, ``temporal_drift`` and its member): a drift
  moves every pixel of a frame together, so the frames' median residuals vary as much as their
  mean residuals; a few outlying pixels move a frame's mean, not its median.

The ranking scales such a candidate's held-out gain by its share
(:func:`~tof_fpn_torch.diagnosis.naming.rank`, ``signature_share`` in the ranking): it is
credited with the part of the misfit that has its signature.
"""

from __future__ import annotations

import math

import torch

from .. import constants as K

__all__ = [
    "COURSE_Z",
    "DEFECT_WINDOW",
    "DEPTH_LAYER_M",
    "FINE_SCALE_PX",
    "OUTLIER_Z",
    "both_shares",
    "common_share",
    "defect_pixels",
    "dense_share",
    "fine_share",
    "sporadic_share",
]

#: Gaussian smoothing scale (px) above which amplitude structure is not per pixel
FINE_SCALE_PX: float = 12.0
#: depth layers (m) the smoothing stays within (neighbouring layers included)
DEPTH_LAYER_M: float = 0.1
#: a frame-pixel this many sd from the model is an outlier
OUTLIER_Z: float = 5.0
#: side (px) of the neighbourhood whose means set the robust spread a defect pixel is beyond
DEFECT_WINDOW: int = 7
#: a frames' course is established when its covariance between two halves of the pixels is
#: this many sd above zero
COURSE_Z: float = 3.0


def _band(n: int, k: torch.Tensor) -> torch.Tensor:
    """The (n, n) matrix of the correlation with the symmetric taps ``k`` (2 r + 1), zeros
    beyond the ends: ``x @ band`` smooths the last axis of ``x``."""
    r = (k.numel() - 1) // 2
    i = torch.arange(n)
    d = i.view(-1, 1) - i.view(1, -1)
    return torch.where(d.abs() <= r, k[(d + r).clamp(0, 2 * r)], torch.zeros((), dtype=k.dtype))


def _blur_layers(x: torch.Tensor, s: float) -> torch.Tensor:
    """Separable Gaussian smoothing (sd ``s`` px, 3 sd each side) of every map of ``x``
    (L, H, W), zeros beyond the frame (the diagnosis layer does not import kornia), as products
    with banded matrices (a float64 ``conv2d`` on the CPU costs fifty times as much)."""
    r = int(3 * s)
    t = torch.arange(-r, r + 1, dtype=x.dtype)
    k = torch.exp(-(t**2) / (2 * s * s))
    k = k / k.sum()
    h, w = x.shape[-2:]
    return _band(h, k) @ (x @ _band(w, k))


def _layers(m: torch.Tensor, depth: torch.Tensor, dtype, s: float) -> tuple:
    """``(layer of every pixel, layers present, their masks (L, H, W), the smoothed masks summed
    over +-1 layer (L, H, W))``: what :func:`_layered_smooth` needs of ``m`` and ``depth``."""
    layer = torch.floor(depth / DEPTH_LAYER_M).long()
    vals = layer[m].unique().tolist()
    sel = torch.stack([(m & (layer == v)) for v in vals]).to(dtype)
    den = _blur_layers(sel, s)
    pos = {v: i for i, v in enumerate(vals)}
    dens = torch.stack(
        [sum(den[pos[u]] for u in (v - 1, v, v + 1) if u in pos) for v in vals]
    ).clamp_min(1e-12)
    return layer, vals, sel, dens


def _layered_smooth(x: torch.Tensor, m: torch.Tensor, depth: torch.Tensor, s: float, held=None):
    """Normalised Gaussian smoothing of ``x`` over the pixels ``m`` within +-1 depth layer
    (``held``: :func:`_layers` of ``m`` and ``depth``, computed here when not given)."""
    layer, vals, sel, dens = _layers(m, depth, x.dtype, s) if held is None else held
    num = _blur_layers(x * sel, s)
    pos = {v: i for i, v in enumerate(vals)}
    out = torch.zeros_like(x)
    for i, v in enumerate(vals):
        n = sum(num[pos[u]] for u in (v - 1, v, v + 1) if u in pos)
        out = torch.where(layer == v, n / dens[i], out)
    return out


def _fine(res: list, noise: list, m, depth, held=None) -> float | None:
    """Share of the excess variance of the residual maps ``res`` (noise variances ``noise``)
    left after the layered smoothing."""
    tot = sum(float((r[m] ** 2).mean() - v[m].mean()) for r, v in zip(res, noise, strict=True))
    if not math.isfinite(tot) or tot <= 0:
        return None
    fine = 0.0
    for r, v in zip(res, noise, strict=True):
        hp = r - _layered_smooth(torch.where(m, r, 0.0), m, depth, FINE_SCALE_PX, held)
        fine += float((hp[m] ** 2).mean() - v[m].mean())
    return min(max(fine / tot, 0.0), 1.0)


def _held_layers(obs, ctx, m, depth) -> tuple:
    """:func:`_layers` of the pixels ``m`` of ``obs`` under ``ctx``, kept on ``ctx`` for those
    observations (the ranking asks for shares in every round, the masks stay)."""
    store = getattr(ctx, "_frames", None)
    if store is None:  # not a diagnosis context: nothing to keep them on
        return _layers(m, depth, depth.dtype, FINE_SCALE_PX)
    key = ("fine_layers",)
    ident = (obs.scene_depth, obs.m_a, obs.m_d, ctx.mask_a, ctx.mask_d)
    entry = store.get(key)
    if entry is None or any(a is not b for a, b in zip(entry[0], ident, strict=True)):
        entry = (ident, _layers(m, depth, depth.dtype, FINE_SCALE_PX))
        store[key] = entry
    return entry[1]


def fine_share(obs, ctx, pred, phasor: bool = False) -> float | None:
    """Share of the excess variance of the residuals finer than ``FINE_SCALE_PX`` (in [0, 1];
    None when there is no excess: nothing to share): of the amplitude residuals, or with
    ``phasor`` of the phasor's residual (radial from the amplitude, tangential from the depth:
    what a complex offset per pixel moves); the smaller of the shares of the residuals in DN
    and relative to the predicted amplitude. A gain's misfit is the gain times the amplitude,
    an offset's is the offset: in the other one's frame each carries the scene's amplitude
    texture, which is fine structure of the scene and not of the misfit (a smooth gain on a
    textured scene looks fine in DN). A misfit fine in both frames is fine."""
    m = ctx.mask_a & ctx.mask_d & torch.isfinite(obs.m_a) & torch.isfinite(obs.m_d)
    if int(m.sum()) < 16:
        return None
    depth = obs.scene_depth.to(torch.float64)
    mu = pred.mu_a.detach().to(torch.float64)
    va = pred.sd_a.detach() ** 2 / obs.n.clamp_min(1)
    res, noise = [obs.m_a - mu], [va]
    if phasor:
        k = 4 * math.pi * float(obs.camera().modulation_frequency) / K.SPEED_OF_LIGHT_AIR
        rd = obs.m_d - pred.mu_d.detach()
        if pred.wrap is not None:
            rd = rd - pred.wrap * torch.round(rd / pred.wrap)
        ka = k * pred.a0.detach()
        res.append(rd * ka)
        noise.append((pred.sd_d.detach() * ka) ** 2 / obs.n.clamp_min(1))
    scale = mu.clamp_min(1e-12)
    held = _held_layers(obs, ctx, m, depth)
    shares = (
        _fine(res, noise, m, depth, held),
        _fine([r / scale for r in res], [v / scale**2 for v in noise], m, depth, held),
    )
    if any(x is None for x in shares):
        return None
    return min(shares)


def _mean_z(obs, ctx, pred) -> tuple[torch.Tensor, torch.Tensor]:
    """The temporal means' residuals in sd of the model's mean (its noise and random effects),
    depth and amplitude (H, W), zero outside ``ctx.mask_d``."""
    n = obs.n.clamp_min(1)
    d = obs.m_d - pred.mu_d.detach()
    if pred.wrap is not None:
        d = d - pred.wrap * torch.round(d / pred.wrap)
    tau_d = torch.as_tensor(getattr(pred, "tau_d", 0.0), dtype=torch.float64)
    tau_a = torch.as_tensor(getattr(pred, "tau_a", 0.0), dtype=torch.float64)
    zd = d / torch.sqrt(pred.sd_d.detach() ** 2 / n + tau_d.detach() ** 2)
    za = (obs.m_a - pred.mu_a.detach()) / torch.sqrt(
        pred.sd_a.detach() ** 2 / n + tau_a.detach() ** 2
    )
    m = ctx.mask_d & torch.isfinite(zd) & torch.isfinite(za)
    zero = torch.zeros_like(zd)
    return torch.where(m, zd, zero), torch.where(m, za, zero)


def _local_robust(z: torch.Tensor, m: torch.Tensor, r: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Median and robust sd (1.4826 MAD) of ``z`` over the pixels ``m`` in the (2 r + 1)^2
    window about every pixel (H, W each; NaN where the window holds none)."""
    x = torch.where(m, z, torch.nan)[None, None]
    x = torch.nn.functional.pad(x, (r, r, r, r), value=float("nan"))
    win = torch.nn.functional.unfold(x, 2 * r + 1)[0]  # (K, H W)
    med = win.nanmedian(0).values
    mad = (win - med).abs().nanmedian(0).values
    h, w = z.shape
    return med.view(h, w), (1.4826 * mad).view(h, w)


def defect_pixels(obs, ctx, pred) -> torch.Tensor:
    """Isolated defect pixels (H, W): the temporal mean of depth or amplitude beyond
    ``OUTLIER_Z`` times the robust spread (1.4826 MAD) of the means in its
    :data:`DEFECT_WINDOW` neighbourhood about their median (a dense pattern's spread changes
    over the frame with the light, a dark region's offsets move the phase more), and at least
    that of all the pixels' means and the noise; no
    8-neighbour such a pixel, and none of the 3 x 3 pixels on a depth edge of the scene (where
    a pixel's footprint mixes two surfaces)."""
    zd, za = _mean_z(obs, ctx, pred)
    m = ctx.mask_d
    far = torch.zeros_like(m)
    if int(m.sum()) < 16:
        return far
    for z in (zd, za):
        med, s = _local_robust(z, m, DEFECT_WINDOW // 2)
        v = z[m]
        s_all = 1.4826 * float((v - v.median()).abs().median())
        far = far | (m & ((z - med).abs() > OUTLIER_Z * s.clamp_min(max(s_all, 1.0))))
    from ..sim import edge_partners

    edge = (edge_partners(obs.scene_depth.to(torch.float64)) >= 0).view_as(far)
    return far & (_around(far) < 1.5) & (_around(edge) < 0.5)


def _around(x: torch.Tensor) -> torch.Tensor:
    """How many of the 3 x 3 pixels about every pixel (itself included) ``x`` holds."""
    f = x.to(torch.float64)[None, None]
    one = torch.ones(1, 1, 3, 3, dtype=torch.float64)
    return torch.nn.functional.conv2d(torch.nn.functional.pad(f, (1, 1, 1, 1)), one)[0, 0]


def dense_share(obs, ctx, pred) -> float | None:
    """Share of the excess spread of the temporal means (depth and amplitude, in sd of the
    model's mean) carried by the pixels that are not isolated defects (None: no excess)."""
    zd, za = _mean_z(obs, ctx, pred)
    m = ctx.mask_d
    if int(m.sum()) < 16:
        return None
    e = (zd**2 + za**2 - 2.0).clamp_min(0.0)
    tot = float(e[m].sum())
    if not math.isfinite(tot) or tot <= 0:
        return None
    return 1.0 - float(e[m & defect_pixels(obs, ctx, pred)].sum()) / tot


def both_shares(a: float | None, b: float | None) -> float | None:
    """The product of two signature shares (either alone where the other is None)."""
    if a is None:
        return b
    if b is None:
        return a
    return a * b


def sporadic_share(obs, ctx, pred) -> float | None:
    """Share of the outlying frame-pixels (depth or amplitude beyond ``OUTLIER_Z`` sd) on pixels
    that are outliers in at most half their frames or are isolated defect pixels
    (:func:`defect_pixels`; None: no outlier, or a single frame)."""
    if obs.frames < 2:
        return None
    d = obs.depth - pred.mu_d.detach()
    if pred.wrap is not None:
        d = d - pred.wrap * torch.round(d / pred.wrap)
    a = obs.amplitude - pred.mu_a.detach()
    far = (d.abs() > OUTLIER_Z * pred.sd_d.detach()) | (a.abs() > OUTLIER_Z * pred.sd_a.detach())
    out = obs.valid & ctx.mask_d & far
    count = out.sum(0)
    total = int(count.sum())
    if total == 0:
        return None
    n = obs.valid.sum(0).clamp_min(1)
    keep = (2 * count <= n) | defect_pixels(obs, ctx, pred)
    return float(count[keep].sum()) / total


def common_share(obs, ctx, pred) -> float | None:
    """The part of the frames' course that every pixel shares: the course of the frames' median
    residual against that of their mean residual (depth and relative amplitude, each in units of
    its typical per-frame noise), in [0, 1]; None for fewer than 3 frames or no course at all.

    Each course is taken on two disjoint halves of the pixels (alternate pixels of the flattened
    frame), and its size is the covariance over the frames of the two halves' courses: the
    halves' own sampling noise is independent and drops out, so a drift small beside the
    per-pixel noise keeps its full share however heavy the noise's tails (with the plain
    variances, the mean's larger sampling noise under heavy tails lowered a real drift's share);
    a few outlying pixels that fire in the same frames still move both halves' means together,
    not their medians. The share is taken only where the means' course is established: their
    covariance at least :data:`COURSE_Z` times its sd under independent halves
    (``sqrt(sum_f v_a,f v_b,f)``, ``v`` the variance of a half's frame mean from its pixels'
    noise in time); a course within its sampling noise (a drift that only the
    likelihood, weighing every pixel by its precision, resolves) says nothing about its
    signature, and the share is None (the held-out gain decides alone)."""
    if obs.frames < 3:
        return None
    m = ctx.mask_d & ctx.mask_a
    if int(m.sum()) < 16:
        return None
    d = obs.depth - pred.mu_d.detach()
    if pred.wrap is not None:
        d = d - pred.wrap * torch.round(d / pred.wrap)
    mu = pred.mu_a.detach().clamp_min(1e-12)
    a = (obs.amplitude - mu) / mu
    ok = obs.valid & m
    num = den = null = 0.0
    for r, sd in ((d, pred.sd_d.detach()), (a, pred.sd_a.detach() / mu)):
        x = torch.where(ok, r, torch.nan).reshape(obs.frames, -1)
        scale = float(sd[m].median()) ** 2 or 1.0
        half = (x[:, 0::2], x[:, 1::2])
        mean = [_centred(h.nanmean(1)) for h in half]
        med = [_centred(h.nanmedian(1).values) for h in half]
        num += float((med[0] * med[1]).nansum()) / scale
        den += float((mean[0] * mean[1]).nansum()) / scale
        va, vb = _sampling_variance(half[0]), _sampling_variance(half[1])
        null += float((va * vb).nansum()) / scale**2
    if not (math.isfinite(den) and math.isfinite(num)) or den <= COURSE_Z * math.sqrt(null):
        return None
    return min(max(num / den, 0.0), 1.0)


def _sampling_variance(x: torch.Tensor) -> torch.Tensor:
    """Per frame, the variance of the mean of ``x`` (F, N) from its pixels' noise in time: the
    spread of each pixel about its own mean over the frames (a misfit fixed in time does not
    move the course), over the frame's valid pixels."""
    n = torch.isfinite(x).sum(1).clamp_min(1)
    dev = x - x.nanmean(0, keepdim=True)
    return float(dev.pow(2).nanmean()) / n


def _centred(x: torch.Tensor) -> torch.Tensor:
    """A course about its mean over the frames (NaN frames stay NaN)."""
    return x - x.nanmean()
