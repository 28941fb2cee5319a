r"""Sliding-window DCT denoising (Yaroslavsky 1996; Foi, Katkovnik, Egiazarian 2007): torch.

Every ``n x n`` window (all positions for ``step = 1``, else a grid of ``step`` pixels, the last
row and column included) is transformed by the orthonormal 2-D DCT; coefficients whose magnitude
is below ``lam`` times the window's noise standard deviation are set to 0 (the DC term is always
kept); the inverse transforms of all windows are averaged with the weight
``1 / (sigma^2 N_kept)`` (sparser windows count more, as in BM3D's first stage) and a Kaiser
window (``beta``; 0 is flat). The transform of every window is one pair of convolutions and the
inverse plus the overlap-add another (:mod:`tof_fpn_torch.denoise.bm3d_core`), so the cost is a
few passes over ``n^2`` coefficients per pixel.

Noise, invalid pixels (push-pull fill, returned unchanged), degenerate inputs: as
:func:`~tof_fpn_torch.denoise.bm3d` (a window's noise variance is the mean of the pixels'). Images
must be at least ``block_size`` pixels per side. TorchScript: ``torch.jit.script`` compiles the
module (tests/test_sliding_dct.py).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from ..runtime.noise import hh_kernel
from ._common import Denoiser, as_sigma, check_k, fill_invalid, noise_map, prepare, restore_invalid
from .bm3d_core import _aggregate, _synthesis, _transform, dct_matrix

__all__ = ["SDCT_BETA", "SDCT_BLOCK_SIZE", "SDCT_LAM", "SDCT_STEP", "SlidingDCT", "sliding_dct"]

# Defaults of sliding_dct and SlidingDCT (written once; see the docstrings)
#: block side ``block_size``
SDCT_BLOCK_SIZE: int = 8
#: grid step of the windows ``step`` (1: every position)
SDCT_STEP: int = 1
#: hard threshold ``lam`` in noise standard deviations
SDCT_LAM: float = 2.7
#: Kaiser window ``beta`` of the aggregation (0: flat)
SDCT_BETA: float = 0.0


def _check(block_size: int, step: int, lam: float, beta: float) -> None:
    if block_size < 2:
        raise ValueError(f"block_size must be an int >= 2, got {block_size}")
    if step < 1 or step > block_size:
        raise ValueError(f"step must be an int in [1, block_size={block_size}], got {step}")
    if not (lam > 0.0 and lam < float("inf")):
        raise ValueError(f"lam must be a finite number > 0, got {lam}")
    if not (beta >= 0.0 and beta < float("inf")):
        raise ValueError(f"beta must be a finite number >= 0, got {beta}")


def _sdct_image(
    x: torch.Tensor, var_map: torch.Tensor, n: int, step: int, lam: float, beta: float
) -> torch.Tensor:
    """One (H, W) image with ``(H - n) % step == 0 == (W - n) % step``."""
    H, W = x.shape
    Hc, Wc = H - n + 1, W - n + 1
    d = dct_matrix(n, x.dtype, x.device)
    kw = torch.kaiser_window(n, periodic=False, beta=beta, dtype=torch.float64)
    kw = kw.to(dtype=x.dtype, device=x.device)
    syn = _synthesis(d, kw, torch.ones(n * n, dtype=x.dtype, device=x.device))
    var = F.avg_pool2d(var_map.reshape(1, 1, H, W), n, stride=1).reshape(Hc * Wc, 1)
    std = var.clamp_min(1e-30).sqrt()
    coef = _transform(x, d).div_(std)  # in units of the window's noise
    dc = coef[:, :1].clone()
    coef = F.hardshrink(coef, lam)
    coef[:, :1] = dc
    kept = (coef != 0).sum(1, keepdim=True).to(x.dtype).clamp_min(1.0)
    w = 1.0 / (var.clamp_min(1e-30) * kept)
    on = torch.zeros(Hc, Wc, dtype=x.dtype, device=x.device)
    on[::step, ::step] = 1.0
    w = w * on.reshape(-1, 1)
    acc = coef.mul_(w * std)
    return _aggregate(acc, w.reshape(-1), syn[0], syn[1], kw, Hc, Wc)


def sliding_dct(
    depth: torch.Tensor,
    amplitude: torch.Tensor | None = None,
    sigma: float | torch.Tensor | None = None,
    block_size: int = SDCT_BLOCK_SIZE,
    step: int = SDCT_STEP,
    lam: float = SDCT_LAM,
    beta: float = SDCT_BETA,
    k: float | None = None,
    signed: bool = False,
) -> torch.Tensor:
    r"""Sliding-window DCT hard-thresholding of (B, C, H, W) depth (module docstring).

    Args:
        depth: (B, C, H, W) floating depth, ``H, W >= block_size``; channels independently.
        amplitude: optional (B, 1, H, W): validity and, without ``sigma``, the noise ``k / A``.
        sigma: noise (number, (B,) tensor, (B, 1, H, W) map, or None: estimated).
        block_size: window side ``n``.
        step: grid step of the windows (1: every position).
        lam: hard threshold in noise standard deviations.
        beta: Kaiser window of the aggregation (0: flat).
        k, signed: as :func:`~tof_fpn_torch.denoise.bm3d`.

    Returns:
        (B, C, H, W), dtype of ``depth``; invalid pixels unchanged.

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> clean = torch.linspace(1.0, 2.0, 32).repeat(1, 1, 32, 1)
        >>> noisy = clean + 0.05 * torch.randn(1, 1, 32, 32, generator=g)
        >>> out = sliding_dct(noisy, sigma=0.05)
        >>> bool((out - clean).abs().mean() < 0.5 * (noisy - clean).abs().mean())
        True
    """
    return _sliding_dct(
        depth,
        amplitude,
        sigma,
        block_size,
        step,
        lam,
        beta,
        k,
        signed,
        hh_kernel(torch.float64, depth.device),
    )


def _sliding_dct(
    depth: torch.Tensor,
    amplitude: torch.Tensor | None,
    sigma: float | torch.Tensor | None,
    block_size: int,
    step: int,
    lam: float,
    beta: float,
    k: float | None,
    signed: bool,
    wavelet: torch.Tensor,
) -> torch.Tensor:
    if not torch.jit.is_scripting():
        sigma = as_sigma(sigma)
    _check(block_size, step, lam, beta)
    x, valid, amp = prepare(depth, amplitude, signed)
    B, C, H, W = x.shape
    n = block_size
    if H < n or W < n:
        raise ValueError(
            f"SlidingDCT needs images of at least block_size x block_size = {n} x {n} pixels, "
            f"got {H} x {W}"
        )
    sig = noise_map(x, valid, amp, sigma, k, wavelet)
    ph = (step - (H - n) % step) % step
    pw = (step - (W - n) % step) % step
    out = x.clone()
    for b in range(B):
        vb = valid[b : b + 1]
        if not bool(vb.any()) or not bool((sig[b] > 0).any()):
            continue
        var = F.pad(fill_invalid(sig[b : b + 1], vb).square(), [0, pw, 0, ph], mode="reflect")
        for c in range(C):
            img = F.pad(fill_invalid(x[b : b + 1, c : c + 1], vb), [0, pw, 0, ph], mode="reflect")
            res = _sdct_image(img[0, 0], var[0, 0], n, step, lam, beta)
            out[b, c] = res[:H, :W]
    return restore_invalid(out, depth, valid)


class SlidingDCT(Denoiser):
    r"""Sliding-window DCT denoiser (module of :func:`sliding_dct`, same parameters).

    ``forward(depth, amplitude=None, sigma=None)``; ``torch.jit.script`` compiles it.

    Example:
        >>> SlidingDCT()(torch.ones(1, 1, 16, 16), sigma=0.1).shape
        torch.Size([1, 1, 16, 16])
    """

    def __init__(
        self,
        block_size: int = SDCT_BLOCK_SIZE,
        step: int = SDCT_STEP,
        lam: float = SDCT_LAM,
        beta: float = SDCT_BETA,
        k: float | None = None,
        signed: bool = False,
    ) -> None:
        super().__init__()
        for name, v in (("block_size", block_size), ("step", step)):
            if isinstance(v, bool) or not isinstance(v, int):
                raise ValueError(f"{name} must be an int, got {v!r}")
        _check(block_size, step, float(lam), float(beta))
        check_k(k)
        self.block_size = block_size
        self.step = step
        self.lam = float(lam)
        self.beta = float(beta)
        self.k: float | None = None if k is None else float(k)
        self.signed = bool(signed)
        self.register_buffer("wavelet", hh_kernel(torch.float64, torch.device("cpu")))

    def extra_repr(self) -> str:
        return f"block_size={self.block_size}, step={self.step}, lam={self.lam}, beta={self.beta}"

    def forward(
        self,
        depth: torch.Tensor,
        amplitude: torch.Tensor | None = None,
        sigma: float | torch.Tensor | None = None,
    ) -> torch.Tensor:
        return _sliding_dct(
            depth,
            amplitude,
            sigma,
            self.block_size,
            self.step,
            self.lam,
            self.beta,
            self.k,
            self.signed,
            self.wavelet,
        )
