r"""How strong the periodic stripes are at each amplitude, and the eq. (11) fusion that follows.

The notch stage's output is ``y = x + w(A) D`` with ``D = H x - x`` the notch filter's change and
``w(A)`` the eq. (11) weight (:class:`~tof_fpn_torch.runtime.AmplitudeFusion`). Where should ``w``
be 1 and where near 0? Write the depth as truth ``t`` plus stripes ``s`` (which the notch removes:
``H s = 0``) plus white noise ``n`` of power ``sigma^2``. Then
``y - t = (1 - w) s + n + w (H n - n) + w (H t - t)``, and with the cross terms zero in
expectation the mean squared error is

.. math::

    E(w) = (1 - w)^2 S - 2 w (1 - h_0) \sigma^2 + w^2 (g_e \sigma^2 + T) + \sigma^2,

``S`` the stripe power, ``h_0`` the filter's centre tap, ``g_e = ||\delta - h||^2``, ``T`` the power
of the scene detail the notch removes. Since ``E[D^2] = S + g_e \sigma^2 + T``, setting
``dE / dw = 0`` gives the weight of least error

.. math::

    w^* = \frac{S + (1 - h_0) \sigma^2}{E[D^2]},

the same ratio the run-time gate's risk check uses per frame (:mod:`tof_fpn_torch.runtime.gate`),
and ``E(w) - E(w^*) = E[D^2] (w - w^*)^2``. This module measures ``S``, ``sigma^2`` and ``E[D^2]``
in amplitude bins (:func:`stripe_power_by_amplitude`) and fits the three numbers of eq. (11) to
``w^*`` by that excess error (:func:`fit_fusion`). The paper's thresholds (70, 350) were chosen for
CamCube stripes whose strength falls with amplitude; a camera whose stripes follow another law,
or whose amplitude is on another scale, gets its own from its frames.

**The stripe power per bin.** Stripes at the notch frequencies are the same down every column
(column stripes; rows: the same on the transposed frames) up to an amplitude factor:
``s(y, x) = g(A(y, x)) c(x)``. Noise and scene detail are not. So:

1. ``D`` is averaged down the columns of the top half of the rows and of the bottom half
   separately (pixels whose ``|D|`` is beyond 4 robust sigmas left out: edges), over all frames;
2. each half's profile is fitted by the sinusoids of the notch frequencies (least squares; a scene
   edge spreads over all frequencies and leaves little in this fit): ``c_top(x)``, ``c_bot(x)``;
3. in each amplitude bin, ``c = mean D p_other`` over its pixels, ``p_other`` the pattern of the
   other half at the pixel's column (``c`` is ``-g(A_bin)`` times the other half's mean ``g`` times
   the pattern's power: the other half's noise and scene are independent of the pixel's own), and
   ``S_bin = c_top c_bot / K`` (``c`` over the bin's pixels of each half), ``K = mean p_top p_bot``
   over the bin's columns (the two halves' cross-power: the pattern's power times both halves'
   mean ``g``, without their own noise or scene): ``g(A_bin)^2`` times the pattern's power, the
   stripe power, with the halves' mean ``g`` cancelled, and 0 in expectation without stripes
   (``c_top``, ``c_bot`` come from different pixels). A bin with too few pixels in one half
   uses ``(c^2 - var c) / K`` over all its pixels (``var c`` the sampling variance of ``c``),
   which assumes equal mean ``g`` in the two halves.
   (A regression of ``D`` on ``p_other`` instead is attenuated by the scene content of the other
   half's pattern, the classical errors-in-variables bias: 2-6x too low on 53 x 71 frames.)

Each notch frequency and orientation is its own pattern; their powers add (they are orthogonal over
the columns).

The noise power is :func:`~tof_fpn_torch.runtime.gate.noise_power` (the ToF law ``k / A`` from the
finest diagonal wavelet coefficients, which have no row or column stripes in them).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from .. import constants as K
from ..runtime import FPNFilter, valid_mask
from ..runtime._checks import check_image, check_same_shape
from ..runtime.gate import noise_power
from ..runtime.noise import mad_to_sigma

__all__ = ["AmplitudeBins", "fit_fusion", "stripe_power_by_amplitude"]

#: the least number of valid pixels per amplitude bin
MIN_BIN_PIXELS = 400
#: a bin's pixels in both halves: the product of the halves' means (else the square of one)
MIN_HALF_PIXELS = 50
#: a scene edge: a central difference of the filtered depth beyond this many robust sigmas
EDGE_SIGMAS = 6.0
#: at most this many amplitude bins (quantiles of the valid pixels' amplitudes)
MAX_BINS = 16


@dataclass(frozen=True)
class AmplitudeBins:
    """Per amplitude bin (tensors of shape (bins,), float64): what :func:`fit_fusion` needs.

    Attributes:
        edges: (bins + 1,) bin edges in the camera's amplitude units.
        amplitude: the median amplitude of each bin.
        pixels: the number of valid pixels in each bin.
        stripe_power: ``S``, the stripes' mean power per pixel (depth units squared).
        noise_power: ``sigma^2``, the mean noise power per pixel.
        change_power: ``E[D^2]``, the mean squared change of the notch filter.
        centre: ``h_0``, the filter's centre tap (its product over the filtered dimensions).
    """

    edges: torch.Tensor
    amplitude: torch.Tensor
    pixels: torch.Tensor
    stripe_power: torch.Tensor
    noise_power: torch.Tensor
    change_power: torch.Tensor
    centre: float

    @property
    def best_weight(self) -> torch.Tensor:
        """``w* = (S + (1 - h_0) sigma^2) / E[D^2]`` per bin, clipped to [0, 1]."""
        num = self.stripe_power + (1.0 - self.centre) * self.noise_power
        return (num / self.change_power.clamp_min(1e-30)).clamp(0.0, 1.0)


def _centre(filt: FPNFilter) -> float:
    t = filt.taps.detach().double()
    c = float(t[t.numel() // 2]) if t.numel() % 2 else float(t.max())
    return c ** len(filt.dims)


def _near_edges(filtered: torch.Tensor, valid: torch.Tensor, dims: list[int], taps: int):
    """Pixels within the filter's reach of a scene edge along a filtered dimension: a central
    difference of the *filtered* depth (no stripes left in it) beyond :data:`EDGE_SIGMAS` robust
    sigmas of all of them. The notch's change there is mostly the edge's, at every frequency, and
    would enter both halves' patterns where the edge spans them (a board, a door frame)."""
    near = torch.zeros_like(valid)
    half = taps // 2
    for d in dims:
        f = filtered if d == -1 else filtered.transpose(-1, -2)
        v = valid if d == -1 else valid.transpose(-1, -2)
        if f.shape[-1] < 3:
            continue
        g = (f[..., 2:] - f[..., :-2]).abs()
        ok = v[..., 2:] & v[..., :-2]
        if not bool(ok.any()):
            continue
        thr = EDGE_SIGMAS * K.MAD_TO_SIGMA * float(g[ok].median())
        edge = torch.nn.functional.pad((ok & (g > thr)).double(), (1, 1))
        flat = edge.reshape(-1, 1, edge.shape[-1])
        grown = torch.nn.functional.max_pool1d(flat, 2 * half + 1, 1, half).reshape(edge.shape)
        grown = grown > 0
        near = near | (grown if d == -1 else grown.transpose(-1, -2))
    return near


def _line_patterns(
    profile: torch.Tensor, has: torch.Tensor, notches: list[float]
) -> list[torch.Tensor]:
    """Least-squares fit of ``profile`` (L,) over ``has`` by cos / sin at ``notches``: the fitted
    sinusoid of each notch frequency, (L,) each (zeros when too few columns)."""
    n = torch.arange(profile.numel(), dtype=torch.float64)
    cols, owner = [], []
    for i, w in enumerate(notches):
        cols.append(torch.cos(w * n))
        owner.append(i)
        if abs(math.sin(w)) > 1e-6:  # at pi the sine is 0 on the grid
            cols.append(torch.sin(w * n))
            owner.append(i)
    basis = torch.stack(cols, 1)
    if int(has.sum()) <= basis.shape[1]:
        return [torch.zeros_like(profile) for _ in notches]
    coef = torch.linalg.lstsq(basis[has], profile[has].unsqueeze(1)).solution.squeeze(1)
    out = [torch.zeros_like(profile) for _ in notches]
    for j, i in enumerate(owner):
        out[i] = out[i] + coef[j] * basis[:, j]
    return out


def _patterns(
    change: torch.Tensor, keep: torch.Tensor, dims: list[int], notches: list[float]
) -> tuple[torch.Tensor, torch.Tensor]:
    """Three (N, 1, H, W, m) tensors: each pixel's line pattern fitted on the other half of the
    rows, on its own half, and its half (0 top, 1 bottom); one per orientation and notch."""
    out, own, side = [], [], []
    for d in dims:
        D, k = (change, keep) if d == -1 else (change.transpose(-1, -2), keep.transpose(-1, -2))
        h = D.shape[-2]
        half = h // 2
        regs = [torch.zeros_like(D) for _ in notches]
        mine = [torch.zeros_like(D) for _ in notches]
        if half >= 1:
            pats = []
            for rows in (slice(0, half), slice(half, h)):
                kk = k[..., rows, :]
                num = torch.where(kk, D[..., rows, :], 0.0).sum((0, 1, 2))
                cnt = kk.sum((0, 1, 2))
                prof = num / cnt.clamp_min(1)
                prof = prof - prof[cnt > 0].mean() if bool((cnt > 0).any()) else prof
                pats.append(_line_patterns(prof, cnt > 0, notches))
            for i, (reg, m) in enumerate(zip(regs, mine, strict=True)):
                reg[..., :half, :], m[..., :half, :] = pats[1][i], pats[0][i]
                reg[..., half:, :], m[..., half:, :] = pats[0][i], pats[1][i]
        out += [r if d == -1 else r.transpose(-1, -2) for r in regs]
        own += [r if d == -1 else r.transpose(-1, -2) for r in mine]
        bottom = torch.zeros_like(D)
        bottom[..., half:, :] = 1.0
        side += [bottom if d == -1 else bottom.transpose(-1, -2)] * len(notches)
    return torch.stack(out, -1), torch.stack(own, -1), torch.stack(side, -1)


def stripe_power_by_amplitude(
    depth: torch.Tensor, amplitude: torch.Tensor, filter: FPNFilter, bins: int | None = None
) -> AmplitudeBins | None:
    """Stripe, noise and change power of the notch ``filter`` in amplitude bins (module docstring).

    Args:
        depth: (N, 1, H, W) frames of one camera (any depth unit; invalid pixels by the one rule).
        amplitude: (N, 1, H, W) their amplitudes (camera units).
        filter: the notch filter whose change is measured; its ``notches`` and ``dims`` say which
            stripes it removes.
        bins: the number of amplitude bins (default: up to 16, at least 400 pixels each).

    Returns:
        the bins, or None when there are fewer than ``2 * MIN_BIN_PIXELS`` valid pixels or the
        filter has no notch frequencies.
    """
    check_image(depth, "depth", 1)
    check_image(amplitude, "amplitude", 1)
    check_same_shape(amplitude, depth, "amplitude", "depth")
    if not isinstance(filter, FPNFilter):
        raise TypeError(f"filter must be an FPNFilter, got {type(filter).__name__}")
    if bins is not None and (isinstance(bins, bool) or not isinstance(bins, int) or bins < 1):
        raise ValueError(f"bins must be an int >= 1 or None, got {bins!r}")
    notches = [float(w) for w in filter.notches]
    valid = valid_mask(depth, amplitude)
    n_valid = int(valid.sum())
    if not notches or n_valid < 2 * MIN_BIN_PIXELS:
        return None
    x = depth.double()
    with torch.no_grad():
        filtered = filter(x)
        change = torch.where(valid, filtered - x, 0.0)
        sigma2 = noise_power(torch.where(valid, x, 0.0), amplitude.double(), valid)
        a = amplitude.double()
        scale = float(mad_to_sigma(change[valid].abs().median(), 1))
        keep = valid & (change.abs() <= 4.0 * scale) if scale > 0 else valid
        keep = keep & ~_near_edges(filtered, valid, list(filter.dims), filter.taps.numel())
        other, own, side = _patterns(change, keep, list(filter.dims), notches)
    nb = bins if bins is not None else max(1, min(MAX_BINS, n_valid // MIN_BIN_PIXELS))
    av = a[valid]
    edges = torch.quantile(av, torch.linspace(0, 1, nb + 1, dtype=torch.float64))
    edges = torch.unique(edges)  # equal quantiles (a clipped amplitude) merge their bins
    index = torch.bucketize(av, edges[1:-1], right=True)
    # the pixels sorted by bin once (stable: each bin keeps the pixels' order), each bin a slice
    order = torch.argsort(index, stable=True)
    counts = torch.bincount(index, minlength=edges.numel() - 1).tolist()
    av, dv, sv, kv = av[order], change[valid][order], sigma2[valid][order], keep[valid][order]
    rv, ov, hv = other[valid][order], own[valid][order], side[valid][order]
    rows = {k: [] for k in ("amplitude", "pixels", "stripe", "noise", "change")}
    start = 0
    for count in counts:
        m = slice(start, start + count)
        start += count
        if count == 0:
            continue
        k = kv[m]
        rows["amplitude"].append(float(av[m].median()))
        rows["pixels"].append(float(count))
        rows["noise"].append(float(sv[m].mean()))
        rows["change"].append(float((dv[m] ** 2).mean()))
        rows["stripe"].append(_bin_stripe_power(dv[m][k], rv[m][k], ov[m][k], hv[m][k]))
    t = {k: torch.tensor(v, dtype=torch.float64) for k, v in rows.items()}
    return AmplitudeBins(
        edges, t["amplitude"], t["pixels"], t["stripe"], t["noise"], t["change"], _centre(filter)
    )


def _bin_stripe_power(
    d: torch.Tensor, other: torch.Tensor, own: torch.Tensor, side: torch.Tensor
) -> float:
    """The stripe power of one bin's pixels (module docstring, step 3), summed over the patterns
    (columns of ``other`` / ``own`` / ``side``, (n, m); different frequencies are orthogonal over
    the columns)."""
    total = 0.0
    for i in range(other.shape[1]):
        cross = float((other[:, i] * own[:, i]).mean()) if d.numel() else 0.0
        if not cross > 0:
            continue
        t = d * other[:, i]
        halves = [t[side[:, i] == h] for h in (0.0, 1.0)]
        if min(x.numel() for x in halves) >= MIN_HALF_PIXELS:
            total += max(float(halves[0].mean() * halves[1].mean()), 0.0) / cross
        elif t.numel() >= 2:
            c, var = float(t.mean()), float(t.var()) / t.numel()
            total += max(c * c - var, 0.0) / cross
    return total


def fit_fusion(bins: AmplitudeBins) -> tuple[float, float, float]:
    """``(low, high, floor)`` of eq. (11) closest to the bins' ``w*`` in excess error.

    Minimises ``sum_b n_b E_b[D^2] (w(A_b) - w*_b)^2`` (module docstring) over ``low`` and
    ``high`` on the grid of bin edges (and one step beyond the largest amplitude, where every
    measured pixel gets weight 1), with ``floor`` in closed form for each pair: ``w`` is affine in
    ``1 - floor``, clipped to ``[0, 1]``.
    """
    a, target = bins.amplitude, bins.best_weight
    cost = bins.pixels * bins.change_power
    top = float(bins.edges[-1])
    cand = sorted({0.0, *[float(e) for e in bins.edges], 2.0 * top + 1.0})
    best = (math.inf, cand[-2], cand[-1], 1.0)
    for i, low in enumerate(cand):
        for high in cand[i + 1 :]:
            ramp = ((a - low) / (high - low)).clamp(0.0, 1.0)
            den = float((cost * ramp * ramp).sum())
            one_minus = float((cost * ramp * (1.0 - target)).sum()) / den if den > 0 else 0.0
            one_minus = min(max(one_minus, 0.0), 1.0)
            w = 1.0 - one_minus * ramp
            err = float((cost * (w - target) ** 2).sum())
            if err < best[0] * (1.0 - 1e-12):
                best = (err, low, high, 1.0 - one_minus)
    return best[1], best[2], best[3]
