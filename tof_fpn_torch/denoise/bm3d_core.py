r"""BM3D kernel (Dabov, Foi, Katkovnik, Egiazarian, IEEE TIP 16(8), 2007): one image, torch only.

Layout (``P = Hc * Wc`` block positions, ``Hc = H - n + 1``; ``H - n`` and ``W - n`` are multiples
of ``step``, which the caller arranges by reflect-padding):

* ``coef`` (P, n^2): the separable 2-D transform (biorthogonal 1.5 in the first stage, DCT in
  the second) of *every* ``n x n`` block, two convolutions; groups are gathered from it, so the
  2-D transform is computed once per image and stage.
* Block matching, on a regular grid of reference blocks (``step``) against every position within
  ``radius`` (``|a - b|^2 = |a|^2 + |b|^2 - 2 a.b``): exact on the pixels (the dot products per
  offset over the whole image, :mod:`~tof_fpn_torch.denoise.bm3d_match`), or on the ``q x q``
  lowest DCT frequencies of each block (one batched matrix product per tile of references;
  ``features = q^2``).
* A group keeps the matched blocks whose mean squared distance per pixel is at most ``tau`` times
  the noise variance of the reference block, at most ``n2``, rounded down to a power of two (Haar
  along the group, as one matrix product); the groups of one size are filtered together.
* Aggregation in the transform domain: the weighted, filtered coefficients of every block are
  added at its position, then two ``conv_transpose2d`` with the Kaiser-windowed synthesis
  vectors do the inverse transform, the window and the overlap-add of all positions at once
  (linear, so equal to aggregating inverse-transformed blocks).

Noise: ``var`` (P,) is the mean noise variance of each block (constant for a scalar sigma) and
``rvar`` (n^2,) the variance of each 2-D coefficient relative to it, from the covariance of a
block's pixels (identity for white noise; from the autocorrelation for a PSD). Coefficients are
divided by ``sqrt(rvar)`` and groups by their noise standard deviation (the mean of their blocks'
``var``), so thresholds and Wiener gains are in units of the noise.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from .bm3d_match import match

__all__ = [
    "bior15_matrix",
    "bm3d_image",
    "check_psd",
    "dct_matrix",
    "psd_block_covariance",
    "separable",
]


def dct_matrix(n: int, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """(n, n) orthonormal DCT-II matrix; row ``k`` is the ``k``-th basis vector."""
    i = torch.arange(n, dtype=torch.float64)
    d = torch.cos(math.pi * (2.0 * i[None, :] + 1.0) * i[:, None] / (2.0 * n)) * math.sqrt(2.0 / n)
    d[0] = d[0] / math.sqrt(2.0)
    return d.to(dtype=dtype, device=device)


def bior15_matrix(n: int, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """(n, n) analysis matrix of the periodised biorthogonal 1.5 wavelet transform, full
    decomposition (``n`` a power of two), rows ordered as ``pywt.wavedec``: approximation, then
    details from coarsest to finest. Filters: ``dec_lo = [3, -3, -22, 22, 128, 128, 22, -22, -3,
    3] / (128 sqrt 2)``, ``dec_hi = [-1, 1] / sqrt 2`` (at taps 4, 5); ``a[k] = sum_j lo[j]
    x[(2k + 5 - j) mod N]`` reproduces pywt's ``periodization`` mode (tests/test_bm3d.py)."""
    r2 = math.sqrt(2.0)
    lo = torch.tensor([3.0, -3.0, -22.0, 22.0, 128.0, 128.0, 22.0, -22.0, -3.0, 3.0]) / (128.0 * r2)
    hi = torch.zeros(10)
    hi[4] = -1.0 / r2
    hi[5] = 1.0 / r2
    cur = torch.eye(n, dtype=torch.float64)
    details: list[torch.Tensor] = []
    size = n
    while size > 1:
        mlo = torch.zeros(size // 2, size, dtype=torch.float64)
        mhi = torch.zeros(size // 2, size, dtype=torch.float64)
        for k in range(size // 2):
            for j in range(10):
                c = (2 * k + 5 - j) % size
                mlo[k, c] += float(lo[j])
                mhi[k, c] += float(hi[j])
        details.insert(0, mhi @ cur)
        cur = mlo @ cur
        size = size // 2
    return torch.cat([cur] + details, 0).to(dtype=dtype, device=device)


def separable(d: torch.Tensor) -> torch.Tensor:
    """(n^2, n^2) 2-D transform of the 1-D matrix ``d``: row ``kx * n + ky``, column
    ``y * n + x`` (the coefficient order of :func:`_transform`)."""
    n = d.shape[0]
    return (d[None, :, :, None] * d[:, None, None, :]).reshape(n * n, n * n)


def _group_sizes(dist: torch.Tensor, limit: torch.Tensor, n2: int) -> torch.Tensor:
    """Blocks per group: those with ``dist <= limit`` (at least the reference), at most ``n2``,
    rounded down to a power of two."""
    count = (dist <= limit[:, None]).sum(1).clamp(1, n2)
    return torch.pow(2, torch.floor(torch.log2(count.double()))).long()


def _haar(x: torch.Tensor, inverse: bool) -> torch.Tensor:
    """Orthonormal Haar transform along dim 1 of (G, m, k), ``m`` a power of two (fast
    butterflies); the output order is [mean, coarsest detail, ..., finest details]."""
    g, m, k = x.shape[0], x.shape[1], x.shape[2]
    c = 1.0 / math.sqrt(2.0)
    if m == 1:
        return x
    if not inverse:
        out = torch.empty_like(x)
        cur = x
        h = m
        while h > 1:
            v = cur.reshape(g, h // 2, 2, k)
            a = v[:, :, 0]
            b = v[:, :, 1]
            torch.sub(a, b, out=out[:, h // 2 : h]).mul_(c)
            cur = torch.add(a, b).mul_(c)
            h = h // 2
        out[:, :1] = cur
        return out
    cur = x[:, :1]
    h = 1
    while h < m:
        s = cur
        d = x[:, h : 2 * h]
        nxt = torch.empty(g, h, 2, k, dtype=x.dtype, device=x.device)
        torch.add(s, d, out=nxt[:, :, 0]).mul_(c)
        torch.sub(s, d, out=nxt[:, :, 1]).mul_(c)
        cur = nxt.reshape(g, 2 * h, k)
        h = 2 * h
    return cur


def _haar_matrix(m: int, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """(m, m) orthonormal Haar matrix of :func:`_haar` (``_haar(x) = H @ x`` along dim 1)."""
    return _haar(torch.eye(m, dtype=dtype, device=device).reshape(1, m, m), False)[0].contiguous()


def _filter_groups(
    coef: torch.Tensor,
    pilot: torch.Tensor | None,
    var: torch.Tensor,
    rvar: torch.Tensor,
    idx: torch.Tensor,
    sizes: torch.Tensor,
    lam: float,
    mu2: float,
    n2: int,
    acc: torch.Tensor,
    wacc: torch.Tensor,
    chunk: int,
) -> None:
    """Collaborative filtering of every group, accumulated into ``acc`` (P, n^2) / ``wacc`` (P,).

    ``coef`` and ``pilot`` are already divided by ``sqrt(rvar)`` (unit relative variance per
    coefficient); thresholds and Wiener gains are in units of each group's noise standard
    deviation. ``pilot`` None: hard thresholding at ``lam``, weight
    ``1 / (var * sum of the kept coefficients' rvar)``; else the empirical Wiener gain
    ``W = P^2 / (P^2 + mu2 var)``, weight ``1 / (var * sum W^2 rvar)``. The Haar transform along
    the group is a matrix product (:func:`_haar_matrix`); groups are processed ``chunk``
    coefficients at a time (in cache)."""
    k = coef.shape[1]
    floor = float(rvar.min()) if pilot is None else 1e-6 * float(rvar.sum())
    m = 1
    while m <= n2:
        sel = torch.nonzero(sizes == m).flatten()
        hm = _haar_matrix(m, coef.dtype, coef.device)
        hmt = hm.t().contiguous()
        step = max(1, chunk // (m * k))
        for g0 in range(0, sel.numel(), step):
            # block-major order (m, g): the Haar transform of every group is one (m, m) @ (m, g k)
            flat = idx[sel[g0 : g0 + step], :m].t().reshape(-1)
            g = flat.numel() // m
            gvar = var.index_select(0, flat).reshape(m, g).mean(0).clamp_min(1e-30)
            gstd = gvar.sqrt().reshape(1, g, 1)
            z = torch.mm(hm, coef.index_select(0, flat).reshape(m, g * k)).reshape(m, g, k)
            if pilot is None:
                z = F.hardshrink(z.div_(gstd), lam)
                kept = (z != 0).sum(0).to(z.dtype)  # (g, k)
                wsum = kept @ rvar
                scale = gstd.reshape(g)
            else:  # P^2 / (P^2 + mu2 var), the group's noise variance not divided out
                p = torch.mm(hm, pilot.index_select(0, flat).reshape(m, g * k)).reshape(m, g, k)
                p.square_()
                gain = p.div_(p + (mu2 * gvar).reshape(1, g, 1))
                z.mul_(gain)
                wsum = gain.square_().sum(0) @ rvar
                scale = torch.ones_like(gvar)
            w = 1.0 / (gvar * wsum.clamp_min(floor))
            z.mul_((w * scale).reshape(1, g, 1))
            out = torch.mm(hmt, z.reshape(m, g * k))
            acc.index_add_(0, flat, out.reshape(m * g, k))
            wacc.index_add_(0, flat, w.repeat(m))
        m *= 2


def _transform(x: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
    """(P, n^2) coefficients ``d B d^T`` of every block ``B`` of the (H, W) image: separable,
    rows then columns; the column pass is a grouped convolution in channels-last layout, whose
    output already is the (P, n^2) table (channel ``kx * n + ky``)."""
    H, W = x.shape
    n = d.shape[0]
    cl = torch.channels_last
    rows = F.conv2d(x.reshape(1, 1, H, W), d.reshape(n, 1, 1, n)).contiguous(memory_format=cl)
    w = d.repeat(n, 1).reshape(n * n, 1, n, 1).contiguous(memory_format=cl)
    cols = F.conv2d(rows, w, groups=n)  # (1, n^2, Hc, Wc), channels-last
    return cols.permute(0, 2, 3, 1).reshape(-1, n * n).contiguous()


def _aggregate(
    acc: torch.Tensor,
    wacc: torch.Tensor,
    synth_y: torch.Tensor,
    synth_x: torch.Tensor,
    kw: torch.Tensor,
    Hc: int,
    Wc: int,
) -> torch.Tensor:
    """Inverse transform + Kaiser window + overlap-add of the accumulated (P, n^2) coefficients,
    separable (columns, then rows), normalised by the overlap-added weights."""
    n = synth_x.shape[-1]
    a = acc.reshape(1, Hc, Wc, n * n).permute(0, 3, 1, 2)
    num = F.conv_transpose2d(F.conv_transpose2d(a, synth_y, groups=n), synth_x)
    den = F.conv_transpose2d(wacc.reshape(1, 1, Hc, Wc), kw.reshape(1, 1, n, 1))
    den = F.conv_transpose2d(den, kw.reshape(1, 1, 1, n))
    return (num / den.clamp_min(1e-30)).reshape(Hc + n - 1, Wc + n - 1)


def _synthesis(d: torch.Tensor, kw: torch.Tensor, rstd: torch.Tensor) -> list[torch.Tensor]:
    """Kernels of the separable inverse of ``d`` with the Kaiser window ``kw`` and the
    coefficient scales ``rstd``: (n^2, 1, n, 1) for the columns, (n, 1, 1, n) for the rows."""
    n = d.shape[0]
    inv = torch.linalg.inv(d.double()).to(d.dtype).t() * kw  # row k: synthesis vector k
    return [
        (inv.repeat(n, 1) * rstd.reshape(-1, 1)).reshape(n * n, 1, n, 1),
        inv.reshape(n, 1, 1, n),
    ]


def bm3d_image(
    x: torch.Tensor,
    var_map: torch.Tensor,
    cov: torch.Tensor,
    n: int,
    step: int,
    radius: int,
    n2_ht: int,
    n2_wiener: int,
    tau_ht: float,
    tau_wiener: float,
    lam: float,
    mu2: float,
    features_wiener: int,
    beta: float,
    transform_ht: str,
    tile: int,
    wiener: bool,
    chunk: int,
) -> torch.Tensor:
    """Denoise one (H, W) image whose ``H - n`` and ``W - n`` are multiples of ``step``.

    ``var_map`` (H, W): noise variance per pixel; ``cov`` (n^2, n^2): covariance of a block's
    pixels (row-major) relative to the pixel variance (identity for white noise); the variance
    of every transform coefficient follows from it. ``transform_ht``: ``'bior1.5'`` or
    ``'dct'`` (2-D transform of the hard-thresholding stage; Wiener: DCT). Matching is exact on
    the pixels in the first stage; in the second on the pixels of the basic estimate
    (``features_wiener = n^2``) or on its ``q x q`` lowest DCT frequencies (``q^2``).
    ``wiener`` False stops after the hard-thresholding stage."""
    H, W = x.shape
    Hc, Wc = H - n + 1, W - n + 1
    dct = dct_matrix(n, x.dtype, x.device)
    d_ht = bior15_matrix(n, x.dtype, x.device) if transform_ht == "bior1.5" else dct
    kw = torch.kaiser_window(n, periodic=False, beta=beta, dtype=torch.float64)
    kw = kw.to(dtype=x.dtype, device=x.device)
    c = cov.to(dtype=x.dtype, device=x.device)
    var = F.avg_pool2d(var_map.reshape(1, 1, H, W), n, stride=1).reshape(-1)  # (P,)
    limit = var.reshape(Hc, Wc)[::step, ::step].reshape(-1) * float(n * n)
    # stage 1: hard thresholding
    t2 = separable(d_ht)
    rv = ((t2 @ c) * t2).sum(1).clamp_min(1e-12)
    rstd = rv.sqrt()
    syn = _synthesis(d_ht, kw, rstd)
    dist, idx = match(x, x[:0], n * n, n, step, radius, tile, n2_ht)
    sizes = _group_sizes(dist, tau_ht * limit, n2_ht)
    coef = _transform(x, d_ht).div_(rstd)
    acc = torch.zeros_like(coef)
    wacc = torch.zeros(coef.shape[0], dtype=x.dtype, device=x.device)
    _filter_groups(coef, None, var, rv, idx, sizes, lam, mu2, n2_ht, acc, wacc, chunk)
    basic = _aggregate(acc, wacc, syn[0], syn[1], kw, Hc, Wc)
    if not wiener:
        return basic
    # stage 2: Wiener filtering with the basic estimate as pilot
    t2 = separable(dct)
    rv = ((t2 @ c) * t2).sum(1).clamp_min(1e-12)
    rstd = rv.sqrt()
    syn = _synthesis(dct, kw, rstd)
    pc = _transform(basic, dct)
    dist, idx = match(basic, pc, features_wiener, n, step, radius, tile, n2_wiener)
    sizes = _group_sizes(dist, tau_wiener * limit, n2_wiener)
    coef = _transform(x, dct).div_(rstd)
    acc.zero_()
    wacc.zero_()
    _filter_groups(coef, pc.div_(rstd), var, rv, idx, sizes, lam, mu2, n2_wiener, acc, wacc, chunk)
    return _aggregate(acc, wacc, syn[0], syn[1], kw, Hc, Wc)


def psd_block_covariance(psd: torch.Tensor, n: int) -> tuple[torch.Tensor, float]:
    """``(cov, var)``: the (n^2, n^2) covariance of the pixels of an ``n x n`` block (row-major)
    relative to the pixel variance ``var``, for stationary noise with power spectrum ``psd``
    (h, w) in the ``bm3d`` package's convention (``E|FFT(noise)|^2``, unnormalised FFT): the
    autocorrelation is ``ifft2(psd) / (h w)``, taken circularly."""
    h, w = psd.shape[-2], psd.shape[-1]
    r = torch.fft.ifft2(psd.to(torch.float64)).real / float(h * w)
    var = float(r[0, 0])
    u = torch.arange(n)
    yy = u.repeat_interleave(n)
    xx = u.repeat(n)
    cov = r[(yy[:, None] - yy[None, :]) % h, (xx[:, None] - xx[None, :]) % w]
    return cov / var, var


def check_psd(psd: torch.Tensor, n: int) -> None:
    """A noise power spectrum for blocks of side ``n``: floating (h, w), h, w >= n, finite, >= 0,
    not all zero (ValueError otherwise)."""
    if psd.dim() != 2 or not psd.is_floating_point():
        raise ValueError(
            f"psd must be a floating (h, w) tensor, got shape {list(psd.shape)} {psd.dtype}"
        )
    if psd.shape[0] < n or psd.shape[1] < n:
        raise ValueError(f"psd must be at least block_size={n} per side, got {list(psd.shape)}")
    if not bool(torch.isfinite(psd).all()) or bool((psd < 0).any()) or not bool((psd > 0).any()):
        raise ValueError("psd must be finite, >= 0 and not all zero")
