r"""BM3D (Dabov, Foi, Katkovnik, Egiazarian, IEEE TIP 16(8), 2007) for depth maps: batched torch.

Two stages, as the paper:

1. **Hard thresholding.** Reference blocks (``block_size`` ``n = 8``) on a grid of ``step``
   pixels; each is matched against every block within ``search_radius`` (exact squared block
   distance); the group of the blocks within ``tau_ht`` times the noise variance (mean squared
   difference per pixel), at most ``max_blocks[0]`` (rounded down to a power of two), is
   transformed (2-D biorthogonal 1.5 wavelet of each block, ``transform_ht="bior1.5"``, or the
   DCT; Haar along the group), coefficients below ``lam`` noise standard deviations are set to 0,
   and the inverse transform is aggregated with weight ``1 / (sigma^2 N_kept)`` and a Kaiser
   window (``beta``).
2. **Wiener filtering.** The same on the basic estimate: matching on it (all ``n^2`` pixels by
   default, ``features_wiener = 64``; ``16`` matches on the 4 x 4 lowest DCT frequencies, faster),
   groups of at most ``max_blocks[1]`` within ``tau_wiener``, gain
   ``|P|^2 / (|P|^2 + mu2 sigma^2)`` (2-D DCT, Haar) from the basic estimate's spectrum ``P``
   applied to the noisy group, weight ``1 / (sigma^2 |W|^2)``.

Implementation: :mod:`tof_fpn_torch.denoise.bm3d_core` (one ``conv2d`` computes the transform of
every block once; matching computes the dot products per offset over the whole image, or a
batched matrix product per tile of references on DCT features,
:mod:`~tof_fpn_torch.denoise.bm3d_match`; aggregation happens in the transform domain).
Defaults follow the ``bm3d`` package (Makinen, Azzari, Foi 2020) for white noise: biorthogonal
1.5 in the first stage, ``lam = 3.0``; the thresholds ``tau`` are relative to the noise variance
(the package's are absolute, for images in [0, 1]: 3000 / 255^2 and 400 / 255^2 per pixel, our
``4.8`` and ``0.64`` at sigma = 25 / 255). Differences: ``mu2 = 1`` (the paper's; the
package 0.4) and a 25 x 25 search window (the package: 39 x 39; ``search_radius=19`` gives it).
Measured against the package: docs/denoise.md.

Noise
-----
``sigma`` as every denoiser of the package (:mod:`tof_fpn_torch.denoise._common`: scalar,
(B, 1, H, W) map, estimated, or ``k / A`` from the amplitude). With a map, a group's variance is
the mean over its blocks of the mean variance of each block. ``psd``: the noise power spectrum
instead, as the ``bm3d`` package takes it (``E|FFT(noise)|^2``, unnormalised FFT, so white noise of
standard deviation ``s`` on an ``h x w`` PSD is ``h * w * s^2`` everywhere): its autocorrelation
gives the exact variance of each 2-D DCT coefficient (blocks of a group are treated as
independent), used by the thresholds, the Wiener gains and the weights. Coloured stripe noise
(e.g. column offsets left by an FPN stage) is thereby described.

Invalid pixels (:func:`~tof_fpn_torch.runtime.valid_mask`) are filled by a push-pull
interpolation before filtering and returned unchanged. Images must be at least
``block_size x block_size``; a search window larger than the image is clipped to it.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from ..runtime.noise import hh_kernel
from ._common import (
    Denoiser,
    as_sigma,
    check_k,
    empty_record,
    fill_invalid,
    noise_map,
    prepare,
    restore_invalid,
)
from .bm3d_core import bm3d_image, check_psd, psd_block_covariance

__all__ = [
    "BM3D",
    "BM3D_BETA",
    "BM3D_BLOCK_SIZE",
    "BM3D_FEATURES_WIENER",
    "BM3D_LAM",
    "BM3D_MAX_BLOCKS",
    "BM3D_MU2",
    "BM3D_SEARCH_RADIUS",
    "BM3D_STEP",
    "BM3D_TAU",
    "BM3D_TRANSFORM_HT",
    "bm3d",
    "psd_block_covariance",
]

# Defaults of bm3d and BM3D (written once; see the docstrings)
#: block side ``block_size``
BM3D_BLOCK_SIZE: int = 8
#: grid step of the reference blocks (``step``)
BM3D_STEP: int = 3
#: block-matching radius (``search_radius``)
BM3D_SEARCH_RADIUS: int = 12
#: largest group, hard thresholding and Wiener (``max_blocks``)
BM3D_MAX_BLOCKS: tuple[int, int] = (16, 32)
#: largest mean squared block distance per pixel over the noise variance, both stages (``tau``)
BM3D_TAU: tuple[float, float] = (4.8, 0.64)
#: hard threshold in noise standard deviations (``lam``)
BM3D_LAM: float = 3.0
#: Wiener regularisation times the noise variance (``mu2``)
BM3D_MU2: float = 1.0
#: features matched in the Wiener stage (``features_wiener``: ``block_size^2`` is exact)
BM3D_FEATURES_WIENER: int = 64
#: Kaiser window parameter of the aggregation (``beta``)
BM3D_BETA: float = 2.0
#: 2-D transform of the hard-thresholding stage (``transform_ht``)
BM3D_TRANSFORM_HT: str = "bior1.5"


def _check_params(
    block_size: int,
    step: int,
    search_radius: int,
    max_blocks: tuple[int, int],
    tau: tuple[float, float],
    lam: float,
    mu2: float,
    features_wiener: int,
    beta: float,
) -> None:
    if block_size < 2:
        raise ValueError(f"block_size must be an int >= 2, got {block_size}")
    if step < 1 or step > block_size:
        raise ValueError(f"step must be an int in [1, block_size={block_size}], got {step}")
    if search_radius < 0:
        raise ValueError(f"search_radius must be an int >= 0, got {search_radius}")
    for mb in max_blocks:
        if mb < 1 or (mb & (mb - 1)) != 0:
            raise ValueError(f"max_blocks must be powers of two >= 1, got {list(max_blocks)}")
    for t in tau:
        if not (t > 0.0 and t < float("inf")):
            raise ValueError(f"tau must be finite numbers > 0, got {list(tau)}")
    if not (lam > 0.0 and lam < float("inf")):
        raise ValueError(f"lam must be a finite number > 0, got {lam}")
    if not (mu2 > 0.0 and mu2 < float("inf")):
        raise ValueError(f"mu2 must be a finite number > 0, got {mu2}")
    q = int(round(features_wiener**0.5))
    if features_wiener != block_size * block_size and (q * q != features_wiener or q > block_size):
        raise ValueError(
            f"features_wiener must be block_size^2 = {block_size * block_size} (exact matching) "
            f"or a square q^2 with q <= block_size, got {features_wiener}"
        )
    if not (beta >= 0.0 and beta < float("inf")):
        raise ValueError(f"beta must be a finite number >= 0, got {beta}")


def _check_transform(transform_ht: str, block_size: int) -> None:
    if transform_ht != "bior1.5" and transform_ht != "dct":
        raise ValueError(f"transform_ht must be 'bior1.5' or 'dct', got '{transform_ht}'")
    if transform_ht == "bior1.5" and (block_size & (block_size - 1)) != 0:
        raise ValueError(
            f"transform_ht='bior1.5' needs a power-of-two block_size, got {block_size}"
        )


def bm3d(
    depth: torch.Tensor,
    amplitude: torch.Tensor | None = None,
    sigma: float | torch.Tensor | None = None,
    psd: torch.Tensor | None = None,
    block_size: int = BM3D_BLOCK_SIZE,
    step: int = BM3D_STEP,
    search_radius: int = BM3D_SEARCH_RADIUS,
    max_blocks: tuple[int, int] = BM3D_MAX_BLOCKS,
    tau: tuple[float, float] = BM3D_TAU,
    lam: float = BM3D_LAM,
    mu2: float = BM3D_MU2,
    features_wiener: int = BM3D_FEATURES_WIENER,
    beta: float = BM3D_BETA,
    transform_ht: str = BM3D_TRANSFORM_HT,
    k: float | None = None,
    signed: bool = False,
    wiener: bool = True,
) -> torch.Tensor:
    r"""BM3D denoising of a batch of depth maps (see the module docstring for the algorithm).

    Args:
        depth: (B, C, H, W) floating depth, ``H, W >= block_size``; channels are denoised
            independently.
        amplitude: optional (B, 1, H, W) amplitude: validity (``A`` NaN or < 0 is invalid) and,
            when neither ``sigma`` nor ``psd`` is given, the noise map ``k / A``.
        sigma: noise standard deviation: number, (B,) tensor, (B, 1, H, W) map, or None.
        psd: noise power spectrum (h, w) instead of ``sigma`` (``bm3d`` package convention).
        block_size: side ``n`` of the blocks.
        step: grid step of the reference blocks.
        search_radius: blocks within ``|dy|, |dx| <= search_radius`` of a reference are matched.
        max_blocks: largest group (hard thresholding, Wiener), powers of two.
        tau: largest mean squared block distance per pixel in a group, relative to the noise
            variance (hard thresholding, Wiener).
        lam: hard threshold in noise standard deviations.
        mu2: Wiener regularisation, times the noise variance.
        features_wiener: ``block_size^2`` to match exactly in the Wiener stage, or ``q^2`` to
            match on the ``q x q`` lowest DCT frequencies of the basic estimate (faster).
        beta: Kaiser window parameter of the aggregation.
        k: ``sigma = k / A`` constant when the amplitude sets the noise (None: estimated).
        signed: the data are a signed image, not depth (only NaN / inf are invalid).
        wiener: False returns the hard-thresholding (basic) estimate.

    Returns:
        (B, C, H, W), dtype of ``depth`` (float16/bfloat16 computed in float32); invalid pixels
        unchanged. Not differentiable.

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> clean = torch.linspace(1.0, 2.0, 48).repeat(1, 1, 48, 1)
        >>> noisy = clean + 0.05 * torch.randn(1, 1, 48, 48, generator=g)
        >>> out = bm3d(noisy, sigma=0.05)
        >>> bool((out - clean).abs().mean() < 0.3 * (noisy - clean).abs().mean())
        True
    """
    return _bm3d(
        depth,
        amplitude,
        sigma,
        psd,
        block_size,
        step,
        search_radius,
        max_blocks,
        tau,
        lam,
        mu2,
        features_wiener,
        beta,
        transform_ht,
        k,
        signed,
        wiener,
        hh_kernel(torch.float64, depth.device),
    )


def _bm3d(
    depth: torch.Tensor,
    amplitude: torch.Tensor | None,
    sigma: float | torch.Tensor | None,
    psd: torch.Tensor | None,
    block_size: int,
    step: int,
    search_radius: int,
    max_blocks: tuple[int, int],
    tau: tuple[float, float],
    lam: float,
    mu2: float,
    features_wiener: int,
    beta: float,
    transform_ht: str,
    k: float | None,
    signed: bool,
    wiener: bool,
    wavelet: torch.Tensor,
) -> torch.Tensor:
    if not torch.jit.is_scripting():
        sigma = as_sigma(sigma)
    _check_params(block_size, step, search_radius, max_blocks, tau, lam, mu2, features_wiener, beta)
    _check_transform(transform_ht, block_size)
    x, valid, amp = prepare(depth, amplitude, signed)
    B, C, H, W = x.shape
    n = block_size
    if H < n or W < n:
        raise ValueError(
            f"BM3D needs images of at least block_size x block_size = {n} x {n} pixels, got "
            f"{H} x {W}"
        )
    cov = torch.eye(n * n, dtype=torch.float64)
    if psd is not None:
        if sigma is not None or amplitude is not None:
            raise ValueError("psd describes the noise: give it without sigma and amplitude")
        check_psd(psd, n)
        cov, pvar = psd_block_covariance(psd.detach().cpu(), n)
        sig = torch.where(valid, torch.full_like(x[:, :1], pvar**0.5), torch.zeros_like(x[:, :1]))
    else:
        sig = noise_map(x, valid, amp, sigma, k, wavelet)
    cov = cov.to(device=x.device, dtype=x.dtype)
    ph = (step - (H - n) % step) % step
    pw = (step - (W - n) % step) % step
    out = x.clone()
    for b in range(B):
        vb = valid[b : b + 1]
        if not bool(vb.any()) or not bool((sig[b] > 0).any()):
            continue  # nothing valid, or no noise: unchanged
        var = fill_invalid(sig[b : b + 1], vb).square()
        var = F.pad(var, [0, pw, 0, ph], mode="reflect")[0, 0]
        for c in range(C):
            img = fill_invalid(x[b : b + 1, c : c + 1], vb)
            img = F.pad(img, [0, pw, 0, ph], mode="reflect")[0, 0]
            res = bm3d_image(
                img,
                var,
                cov,
                n,
                step,
                search_radius,
                max_blocks[0],
                max_blocks[1],
                tau[0],
                tau[1],
                lam,
                mu2,
                features_wiener,
                beta,
                transform_ht,
                4,
                wiener,
                524288,  # coefficients per chunk of groups (in cache)
            )
            out[b, c] = res[:H, :W]
    return restore_invalid(out, depth, valid)


class BM3D(Denoiser):
    r"""BM3D denoiser for (B, C, H, W) depth (thin module over :func:`bm3d`; same parameters).

    ``forward(depth, amplitude=None, sigma=None, psd=None)``. TorchScript: ``torch.jit.script``
    works and gives the eager results (tests/test_bm3d.py).

    Example:
        >>> BM3D(search_radius=4)(torch.ones(1, 1, 16, 16), sigma=0.1).shape
        torch.Size([1, 1, 16, 16])
    """

    def __init__(
        self,
        block_size: int = BM3D_BLOCK_SIZE,
        step: int = BM3D_STEP,
        search_radius: int = BM3D_SEARCH_RADIUS,
        max_blocks: tuple[int, int] = BM3D_MAX_BLOCKS,
        tau: tuple[float, float] = BM3D_TAU,
        lam: float = BM3D_LAM,
        mu2: float = BM3D_MU2,
        features_wiener: int = BM3D_FEATURES_WIENER,
        beta: float = BM3D_BETA,
        transform_ht: str = BM3D_TRANSFORM_HT,
        k: float | None = None,
        signed: bool = False,
        wiener: bool = True,
    ) -> None:
        super().__init__()
        ints = {"block_size": block_size, "step": step, "search_radius": search_radius}
        ints["features_wiener"] = features_wiener
        for name, v in ints.items():
            if isinstance(v, bool) or not isinstance(v, int):
                raise ValueError(f"{name} must be an int, got {v!r}")
        mb = tuple(int(v) for v in max_blocks)
        tt = tuple(float(v) for v in tau)
        if len(mb) != 2 or len(tt) != 2:
            raise ValueError(f"max_blocks and tau are pairs, got {max_blocks!r}, {tau!r}")
        _check_params(block_size, step, search_radius, mb, tt, lam, mu2, features_wiener, beta)
        _check_transform(transform_ht, block_size)
        check_k(k)
        self.block_size = block_size
        self.step = step
        self.search_radius = search_radius
        self.max_blocks: tuple[int, int] = (mb[0], mb[1])
        self.tau: tuple[float, float] = (tt[0], tt[1])
        self.lam = float(lam)
        self.mu2 = float(mu2)
        self.features_wiener = features_wiener
        self.beta = float(beta)
        self.transform_ht = transform_ht
        self.k: float | None = None if k is None else float(k)
        self.signed = bool(signed)
        self.wiener = bool(wiener)
        self.register_buffer("wavelet", hh_kernel(torch.float64, torch.device("cpu")))

    def extra_repr(self) -> str:
        return (
            f"block_size={self.block_size}, step={self.step}, search_radius={self.search_radius}, "
            f"max_blocks={self.max_blocks}, tau={self.tau}, lam={self.lam}, mu2={self.mu2}, "
            f"features_wiener={self.features_wiener}, wiener={self.wiener}"
        )

    def _run(
        self, depth: torch.Tensor, amplitude: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        return self.forward(depth, amplitude, None, None), empty_record()

    def forward(
        self,
        depth: torch.Tensor,
        amplitude: torch.Tensor | None = None,
        sigma: float | torch.Tensor | None = None,
        psd: torch.Tensor | None = None,
    ) -> torch.Tensor:
        return _bm3d(
            depth,
            amplitude,
            sigma,
            psd,
            self.block_size,
            self.step,
            self.search_radius,
            self.max_blocks,
            self.tau,
            self.lam,
            self.mu2,
            self.features_wiener,
            self.beta,
            self.transform_ht,
            self.k,
            self.signed,
            self.wiener,
            self.wavelet,
        )
