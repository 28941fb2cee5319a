r"""Hypothesis bilateral filtering (Yang, Yang, Davis, Nister, CVPR 2007) for ToF depth: torch.

Yang et al. refine a depth map by bilateral filtering of a cost volume: depth hypotheses ``d_i``,
the truncated quadratic cost ``min((d_i - D(q))^2, tau^2)`` of every hypothesis at every pixel,
each cost slice filtered by a joint (cross) bilateral filter guided by the colour image, the best
hypothesis per pixel, refined to sub-hypothesis precision by the vertex of the parabola through
its cost and its two neighbours' costs; iterated.

Here (ToF, noise ``sigma_D(A)`` known per pixel):

* the guide is the amplitude (the depth itself when none is given); the range sigma is ``color``
  times the guide's noise (the amplitude's, estimated per image; or the depth noise at the centre
  pixel) unless ``sigma_color`` is given; spatial Gaussian ``sigma_space`` over a
  ``kernel_size`` window;
* the truncation follows the noise, ``tau(p) = trunc * sigma(p)``: a depth further than ``trunc``
  noise standard deviations is an outlier (another surface), however far;
* the hypotheses are local: ``L = hypotheses`` values from ``D(p) - tau(p)`` to ``D(p) + tau(p)``
  around the current estimate of each pixel (spacing ``2 tau / (L - 1)``, a fraction of the
  noise), instead of one global set over the whole depth range, whose spacing (7 m / 32 levels =
  22 cm) would be far coarser than ToF noise of a centimetre. The cost of hypothesis ``d_i(p)``
  is accumulated over the window directly (``sum_q w(p, q) min((d_i(p) - D(q))^2, tau(p)^2)``),
  which is what filtering a global slice computes for a global ``d_i``.

Untruncated, the cost is a parabola whose vertex is the bilateral-weighted mean of the depths;
the truncation makes the estimate robust (mode-seeking) at depth edges, where a bilateral average
mixes the two sides.

Invalid pixels: weight 0 and returned unchanged. TorchScript: ``torch.jit.script`` compiles the
module (pure torch: shifted slices per tap).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from ..runtime.noise import hh_kernel, wavelet_sigma
from ._common import Denoiser, as_sigma, check_k, noise_map, prepare, restore_invalid

__all__ = [
    "HYPBI_COLOR",
    "HYPBI_HYPOTHESES",
    "HYPBI_ITERATIONS",
    "HYPBI_KERNEL_SIZE",
    "HYPBI_SIGMA_SPACE",
    "HYPBI_TRUNC",
    "HypothesisBilateral",
    "hypothesis_bilateral",
]

# Defaults of hypothesis_bilateral and HypothesisBilateral (written once; see the docstrings)
#: hypotheses ``L`` per pixel (``hypotheses``; odd keeps the current depth one)
HYPBI_HYPOTHESES: int = 13
#: bilateral window side ``kernel_size``
HYPBI_KERNEL_SIZE: int = 7
#: spatial standard deviation ``sigma_space`` (pixels)
HYPBI_SIGMA_SPACE: float = 2.0
#: range sigma in units of the guide's noise (``color``)
HYPBI_COLOR: float = 2.0
#: cost truncation and hypothesis half-range in noise standard deviations (``trunc``)
HYPBI_TRUNC: float = 3.0
#: cost-volume passes (``iterations``)
HYPBI_ITERATIONS: int = 1


def _check(
    hypotheses: int,
    kernel_size: int,
    sigma_space: float,
    color: float,
    sigma_color: float | None,
    trunc: float,
    iterations: int,
) -> None:
    if hypotheses < 3:
        raise ValueError(f"hypotheses must be an int >= 3, got {hypotheses}")
    if kernel_size < 1 or kernel_size % 2 == 0:
        raise ValueError(f"kernel_size must be an odd int >= 1, got {kernel_size}")
    if not (sigma_space > 0.0 and sigma_space < float("inf")):
        raise ValueError(f"sigma_space must be a finite number > 0, got {sigma_space}")
    if not (color > 0.0 and color < float("inf")):
        raise ValueError(f"color must be a finite number > 0, got {color}")
    if not (trunc > 0.0 and trunc < float("inf")):
        raise ValueError(f"trunc must be a finite number > 0, got {trunc}")
    if sigma_color is not None:
        if not (sigma_color > 0.0 and sigma_color < float("inf")):
            raise ValueError(f"sigma_color must be None or a finite number > 0, got {sigma_color}")
    if iterations < 1:
        raise ValueError(f"iterations must be an int >= 1, got {iterations}")


def _check_ints(**values) -> None:
    for name, v in values.items():
        if isinstance(v, bool) or not isinstance(v, int):
            raise ValueError(f"{name} must be an int, got {v!r}")


def _hypbi_core(
    x: torch.Tensor,
    m: torch.Tensor,
    sig: torch.Tensor,
    guide: torch.Tensor,
    scale: torch.Tensor,
    hypotheses: int,
    kernel_size: int,
    sigma_space: float,
    trunc: float,
    iterations: int,
) -> torch.Tensor:
    """One (1, 1, H, W) depth ``x`` (0 where ``m`` is 0), its noise ``sig``, the guide and the
    per-pixel range factor ``scale = -1 / (2 sigma_color^2)`` (1, 1, H, W)."""
    L = hypotheses
    r = kernel_size // 2
    H, W = x.shape[-2], x.shape[-1]
    tau = trunc * sig  # (1, 1, H, W)
    tau2 = tau.square()
    off = torch.linspace(-1.0, 1.0, L, dtype=x.dtype, device=x.device).reshape(1, L, 1, 1)
    step = 2.0 * tau / (L - 1)
    gp = F.pad(guide, [r, r, r, r], mode="replicate")
    mp = F.pad(m, [r, r, r, r], mode="constant", value=0.0)
    cur = x
    for _ in range(iterations):
        hyp = cur + off * tau  # (1, L, H, W)
        dp = F.pad(cur * m, [r, r, r, r], mode="constant", value=0.0)
        cost = torch.zeros(1, L, H, W, dtype=x.dtype, device=x.device)
        norm = torch.zeros(1, 1, H, W, dtype=x.dtype, device=x.device)
        for dy in range(kernel_size):
            for dx in range(kernel_size):
                ws = math.exp(-((dy - r) ** 2 + (dx - r) ** 2) / (2.0 * sigma_space**2))
                g = gp[:, :, dy : dy + H, dx : dx + W] - guide
                w = torch.exp(g.square() * scale) * (ws * mp[:, :, dy : dy + H, dx : dx + W])
                dq = dp[:, :, dy : dy + H, dx : dx + W]
                cost.addcmul_(torch.minimum((hyp - dq).square(), tau2), w)
                norm.add_(w)
        cost = cost / norm.clamp_min(1e-30)
        i = cost.argmin(1, keepdim=True)
        c1 = torch.gather(cost, 1, i)
        c0 = torch.gather(cost, 1, (i - 1).clamp_min(0))
        c2 = torch.gather(cost, 1, (i + 1).clamp_max(L - 1))
        den = c0 + c2 - 2.0 * c1
        o = torch.where(den > 0, (c0 - c2) / (2.0 * den).clamp_min(1e-30), torch.zeros_like(den))
        o = torch.where((i > 0) & (i < L - 1), o.clamp(-0.5, 0.5), torch.zeros_like(o))
        cur = torch.where(m > 0, cur - tau + (i.to(x.dtype) + o) * step, cur)
    return cur


def hypothesis_bilateral(
    depth: torch.Tensor,
    amplitude: torch.Tensor | None = None,
    sigma: float | torch.Tensor | None = None,
    hypotheses: int = HYPBI_HYPOTHESES,
    kernel_size: int = HYPBI_KERNEL_SIZE,
    sigma_space: float = HYPBI_SIGMA_SPACE,
    color: float = HYPBI_COLOR,
    sigma_color: float | None = None,
    trunc: float = HYPBI_TRUNC,
    iterations: int = HYPBI_ITERATIONS,
    k: float | None = None,
    signed: bool = False,
) -> torch.Tensor:
    r"""Hypothesis (cost-volume) bilateral refinement of (B, C, H, W) depth (module docstring).

    Args:
        depth: (B, C, H, W) floating depth (channels independently).
        amplitude: optional (B, 1, H, W): the guide, validity and, without ``sigma``, the noise
            ``k / A``.
        sigma: depth noise (number, (B,) tensor, (B, 1, H, W) map, or None: estimated).
        hypotheses: number ``L`` of hypotheses per pixel (odd keeps the current depth one).
        kernel_size, sigma_space: the bilateral window and its spatial Gaussian (pixels).
        color: range sigma in units of the guide's noise; ``sigma_color``: a fixed one instead.
        trunc: cost truncation and hypothesis half-range, in noise standard deviations.
        iterations: cost-volume passes, each around the previous estimate.
        k, signed: as :func:`~tof_fpn_torch.denoise.bm3d`.

    Returns:
        (B, C, H, W), dtype of ``depth``; invalid pixels unchanged; images without noise or
        without valid pixels unchanged.
    """
    _check_ints(hypotheses=hypotheses, kernel_size=kernel_size, iterations=iterations)
    return _hypothesis_bilateral(
        depth,
        amplitude,
        sigma,
        hypotheses,
        kernel_size,
        float(sigma_space),
        float(color),
        None if sigma_color is None else float(sigma_color),
        float(trunc),
        iterations,
        k,
        signed,
        hh_kernel(torch.float64, depth.device),
    )


def _hypothesis_bilateral(
    depth: torch.Tensor,
    amplitude: torch.Tensor | None,
    sigma: float | torch.Tensor | None,
    hypotheses: int,
    kernel_size: int,
    sigma_space: float,
    color: float,
    sigma_color: float | None,
    trunc: float,
    iterations: int,
    k: float | None,
    signed: bool,
    wavelet: torch.Tensor,
) -> torch.Tensor:
    if not torch.jit.is_scripting():
        sigma = as_sigma(sigma)
    _check(hypotheses, kernel_size, sigma_space, color, sigma_color, trunc, iterations)
    x, valid, amp = prepare(depth, amplitude, signed)
    B, C, H, W = x.shape
    wk = wavelet.to(dtype=x.dtype, device=x.device)
    sig = noise_map(x, valid, amp, sigma, k, wk)
    m = valid.to(x.dtype)
    out = x.clone()
    for b in range(B):
        vb = valid[b : b + 1]
        sb = sig[b : b + 1]
        if not bool(vb.any()) or not bool((sb > 0).any()):
            continue
        mb = m[b : b + 1]
        for c in range(C):
            d = torch.where(vb, x[b : b + 1, c : c + 1], torch.zeros_like(sb))
            if amp is not None:
                guide = torch.where(vb, amp[b : b + 1], torch.zeros_like(sb))
                if sigma_color is None:
                    sa = wavelet_sigma(guide, vb, wk).reshape(1, 1, 1, 1)
                    sc = color * sa
                else:
                    sc = torch.full([1, 1, 1, 1], sigma_color, dtype=x.dtype, device=x.device)
            else:
                guide = d
                if sigma_color is None:
                    sc = color * sb
                else:
                    sc = torch.full([1, 1, 1, 1], sigma_color, dtype=x.dtype, device=x.device)
            scale = -0.5 / sc.clamp_min(1e-30).square()
            res = _hypbi_core(
                d, mb, sb, guide, scale, hypotheses, kernel_size, sigma_space, trunc, iterations
            )
            out[b, c] = res[0, 0]
    return restore_invalid(out, depth, valid)


class HypothesisBilateral(Denoiser):
    """Hypothesis bilateral refinement of ToF depth (Yang et al. 2007) guided by the amplitude.

    Module of :func:`hypothesis_bilateral` (same parameters); ``forward(depth, amplitude=None,
    sigma=None)``; ``torch.jit.script`` compiles it.
    """

    def __init__(
        self,
        hypotheses: int = HYPBI_HYPOTHESES,
        kernel_size: int = HYPBI_KERNEL_SIZE,
        sigma_space: float = HYPBI_SIGMA_SPACE,
        color: float = HYPBI_COLOR,
        sigma_color: float | None = None,
        trunc: float = HYPBI_TRUNC,
        iterations: int = HYPBI_ITERATIONS,
        k: float | None = None,
        signed: bool = False,
    ) -> None:
        super().__init__()
        _check_ints(hypotheses=hypotheses, kernel_size=kernel_size, iterations=iterations)
        _check(hypotheses, kernel_size, sigma_space, color, sigma_color, trunc, iterations)
        check_k(k)
        self.hypotheses = hypotheses
        self.kernel_size = kernel_size
        self.sigma_space = float(sigma_space)
        self.color = float(color)
        self.sigma_color: float | None = None if sigma_color is None else float(sigma_color)
        self.trunc = float(trunc)
        self.iterations = iterations
        self.k: float | None = None if k is None else float(k)
        self.signed = bool(signed)
        self.register_buffer("wavelet", hh_kernel(torch.float64, torch.device("cpu")))

    def forward(
        self,
        depth: torch.Tensor,
        amplitude: torch.Tensor | None = None,
        sigma: float | torch.Tensor | None = None,
    ) -> torch.Tensor:
        return _hypothesis_bilateral(
            depth,
            amplitude,
            sigma,
            self.hypotheses,
            self.kernel_size,
            self.sigma_space,
            self.color,
            self.sigma_color,
            self.trunc,
            self.iterations,
            self.k,
            self.signed,
            self.wavelet,
        )
