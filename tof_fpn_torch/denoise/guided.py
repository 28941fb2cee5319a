r"""Guided filter (He, Sun, Tang, ECCV 2010) for ToF depth, built on ``kornia.filters.guided_blur``.

The filter is kornia's (box means over a ``kernel_size`` window, per-window linear model
``q = a I + b`` with ``a = cov(I, p) / (var(I) + eps)``, reflected borders). What ToF data need
and kornia lacks:

* **Invalid pixels** (:func:`~tof_fpn_torch.runtime.valid_mask`) are replaced, before filtering,
  by a push-pull interpolation of the valid ones (:func:`~tof_fpn_torch.denoise._common.
  fill_invalid`) in both the input and the guide, and returned unchanged. (The guided filter's
  window statistics are means inside kornia's function, which a wrapper cannot mask; filling keeps
  a hole at depth 0, or a NaN, out of every window's mean and variance.)
* **A regulariser that follows the noise**: ``eps = (color * sigma(p))^2`` per pixel with the
  package's noise rules (:mod:`tof_fpn_torch.denoise._common`; with an amplitude and no sigma the
  ToF law ``sigma_D = k / A``): a window whose depth varies by less than about the noise is
  flattened, a larger step is kept. kornia takes one ``eps`` per image: the filter runs at a few
  levels and is interpolated per pixel (:mod:`tof_fpn_torch.denoise._levels`); one noise level
  per image is one exact kornia call. ``eps=`` (absolute) overrides it.

``guide='depth'`` (default) is the self-guided filter (edge-preserving smoothing of the depth);
``guide='amplitude'`` uses the amplitude, with ``eps`` in squared amplitude units: ``color`` times
the amplitude's estimated noise, squared, unless ``eps`` is given. When every pixel is valid and
``eps`` is one number, the result is ``kornia.filters.guided_blur``'s, bit for bit.

TorchScript: not supported -- kornia's functions are not scriptable. ``torch.jit.trace`` runs but
records the data-dependent choices of the traced frame (the number of levels), so it is no
general export.
"""

from __future__ import annotations

import torch
from kornia.filters import guided_blur

from ..runtime.noise import hh_kernel, wavelet_sigma
from ._common import (
    Denoiser,
    as_sigma,
    check_k,
    check_window,
    fill_invalid,
    noise_map,
    prepare,
    restore_invalid,
)
from ._levels import LEVEL_RATIO, MAX_LEVELS, blend, check_levels, levels

__all__ = ["GUIDED_COLOR", "GUIDED_GUIDE", "GUIDED_KERNEL_SIZE", "Guided", "guided"]

# Defaults of guided and Guided (written once; see the docstrings)
#: window side ``kernel_size`` (odd)
GUIDED_KERNEL_SIZE: int = 9
#: ``eps = (color * sigma(p))^2`` (``color``)
GUIDED_COLOR: float = 2.0
#: the guide (``guide``: ``'depth'``, self-guided, or ``'amplitude'``)
GUIDED_GUIDE: str = "depth"


def _check(kernel_size: int, color: float, eps: float | None, guide: str) -> None:
    if isinstance(kernel_size, bool) or not isinstance(kernel_size, int) or kernel_size < 1:
        raise ValueError(f"kernel_size must be an odd int >= 1, got {kernel_size!r}")
    if kernel_size % 2 == 0:
        raise ValueError(f"kernel_size must be odd, got {kernel_size}")
    if not (color > 0 and color < float("inf")):
        raise ValueError(f"color must be a finite number > 0, got {color!r}")
    if eps is not None and not (eps > 0 and eps < float("inf")):
        raise ValueError(f"eps must be None or a finite number > 0, got {eps!r}")
    if guide not in ("depth", "amplitude"):
        raise ValueError(f"guide must be 'depth' or 'amplitude', got {guide!r}")


def guided(
    depth: torch.Tensor,
    amplitude: torch.Tensor | None = None,
    sigma: float | torch.Tensor | None = None,
    kernel_size: int = GUIDED_KERNEL_SIZE,
    color: float = GUIDED_COLOR,
    eps: float | None = None,
    guide: str = GUIDED_GUIDE,
    k: float | None = None,
    signed: bool = False,
    ratio: float = LEVEL_RATIO,
    max_levels: int = MAX_LEVELS,
) -> torch.Tensor:
    r"""Guided filter of (B, C, H, W) depth (kornia's, with holes and a noise-following ``eps``).

    Args:
        depth: (B, C, H, W) floating depth.
        amplitude: optional (B, 1, H, W): validity, the noise ``k / A`` without ``sigma``, and
            the guide for ``guide='amplitude'``.
        sigma: depth noise (number, (B,) tensor, (B, 1, H, W) map, or None: estimated).
        kernel_size: odd window side (kornia ``kernel_size``, ``2 r + 1``).
        color: ``eps = (color * sigma(p))^2`` (guide units).
        eps: a fixed ``eps`` instead (kornia's behaviour).
        guide: ``'depth'`` (self-guided) or ``'amplitude'``.
        k, signed, ratio, max_levels: as :func:`~tof_fpn_torch.denoise.bilateral.bilateral`.

    Returns:
        (B, C, H, W), dtype of ``depth``; invalid pixels unchanged; images without noise or
        without valid pixels unchanged.
    """
    sigma = as_sigma(sigma)
    _check(kernel_size, color, eps, guide)
    if guide == "amplitude" and amplitude is None:
        raise ValueError("guide='amplitude' needs the amplitude")
    x, valid, amp = prepare(depth, amplitude, signed)
    B, C, H, W = x.shape
    if B == 0 or H == 0 or W == 0:
        return depth.clone()
    check_window(H, W, kernel_size, "guided")
    wavelet = hh_kernel(x.dtype, x.device)
    if guide == "amplitude":
        assert amp is not None
        g = fill_invalid(amp, valid)
        if eps is None:
            sa = wavelet_sigma(torch.where(valid, amp, torch.zeros_like(amp)), valid, wavelet)
            rsig = (color * sa.reshape(B, 1, 1, 1)).expand(B, 1, H, W)
        else:
            rsig = torch.full((B, 1, H, W), eps**0.5, dtype=x.dtype, device=x.device)
    else:
        g = None
        if eps is None:
            rsig = color * noise_map(x, valid, amp, sigma, k, wavelet)
        else:
            rsig = torch.full((B, 1, H, W), eps**0.5, dtype=x.dtype, device=x.device)
    live = (
        torch.where(valid, rsig, torch.zeros_like(rsig)).flatten(1).amax(1) > 0
    ) & valid.flatten(1).any(1)
    out = x.clone()
    idx = torch.nonzero(live).flatten()
    if idx.numel() > 0:
        xs, vs, rs = x[idx], valid[idx], rsig[idx]
        top = torch.where(vs, rs, torch.zeros_like(rs)).flatten(1).amax(1).reshape(-1, 1, 1, 1)
        rs = torch.maximum(rs, 1e-6 * top)
        xf = fill_invalid(xs, vs)
        gf = xf if g is None else g[idx]
        lv = levels(rs, vs, ratio, max_levels)  # (b, L) levels of sqrt(eps)
        L = lv.shape[1]
        e: float | torch.Tensor = eps if eps is not None else lv.reshape(-1).square()
        res = guided_blur(gf.repeat_interleave(L, 0), xf.repeat_interleave(L, 0), kernel_size, e)
        out[idx] = blend(res.reshape(idx.numel(), L, C, H, W), lv, rs)
    return restore_invalid(out, depth, valid)


class Guided(Denoiser):
    """Guided filter (kornia) with filled holes and an ``eps`` following the noise.

    Module of :func:`guided` (same parameters); ``forward(depth, amplitude=None, sigma=None)``.
    Not scriptable (kornia's functions are not); see the module docstring.
    """

    def __init__(
        self,
        kernel_size: int = GUIDED_KERNEL_SIZE,
        color: float = GUIDED_COLOR,
        eps: float | None = None,
        guide: str = GUIDED_GUIDE,
        k: float | None = None,
        signed: bool = False,
        ratio: float = LEVEL_RATIO,
        max_levels: int = MAX_LEVELS,
    ) -> None:
        super().__init__()
        _check(kernel_size, color, eps, guide)
        check_levels(ratio, max_levels)
        check_k(k)
        self.kernel_size, self.color, self.eps, self.guide = kernel_size, color, eps, guide
        self.k, self.signed, self.ratio, self.max_levels = k, signed, float(ratio), max_levels

    def forward(self, depth, amplitude=None, sigma=None):
        return guided(
            depth,
            amplitude,
            sigma,
            self.kernel_size,
            self.color,
            self.eps,
            self.guide,
            self.k,
            self.signed,
            self.ratio,
            self.max_levels,
        )
