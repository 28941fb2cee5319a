r"""Anisotropic LPA-ICI denoising (Katkovnik, Foi, Egiazarian, Astola 2004-2006): torch.

Local polynomial approximation (LPA) with directional kernels and the intersection of confidence
intervals (ICI) rule for the adaptive scale:

* **Kernels.** For each of ``directions`` (8) directions ``theta`` and each scale ``h`` in
  ``scales``, the kernel ``g_{theta,h}`` is the LPA of ``order`` 0 (a mean) or 1 (a line along
  ``theta``, evaluated at the centre) over the sector of angular width ``2 pi / directions``
  pointing at ``theta``, radius ``h - 1`` pixels (``h = 1`` is the pixel alone, so the
  smallest scale is unbiased at any edge and the ICI can reject every larger one), centre
  included, uniform window. All
  ``directions x scales`` kernels are one ``conv2d``.
* **ICI.** Per pixel and direction, the estimates ``y_h`` with standard deviations ``s_h`` (exact
  for a noise map: ``s_h^2 = sum g_h^2 sigma^2``) give intervals ``[y_h - gamma s_h, y_h + gamma
  s_h]``; the adaptive scale ``h+`` is the largest ``h`` whose interval still intersects all the
  smaller scales' intervals (running maximum of the lower and minimum of the upper bounds).
* **Fusion.** The directional estimates at their adaptive scales are averaged with weights
  ``1 / s_{h+}^2`` (inverse variances).

So a pixel near an edge averages along the edge (long sectors) and not across it (short ones).

Invalid pixels: order 0 uses normalised convolution (a kernel's weights renormalised over the
valid pixels of its sector, with the variance to match); order 1 works on the push-pull filled
image. Invalid pixels are returned unchanged. Noise rules, degenerate inputs: as every denoiser
(:mod:`tof_fpn_torch.denoise._common`). TorchScript: ``torch.jit.script`` compiles the module.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from ..runtime.noise import hh_kernel
from ._common import Denoiser, as_sigma, check_k, fill_invalid, noise_map, prepare, restore_invalid

__all__ = [
    "LPAICI",
    "LPA_DIRECTIONS",
    "LPA_GAMMA",
    "LPA_ORDER",
    "LPA_SCALES",
    "lpa_ici",
    "lpa_kernels",
]

# Defaults of lpa_ici and LPAICI (written once; see the docstrings)
#: kernel directions (``directions``)
LPA_DIRECTIONS: int = 8
#: increasing scales ``h`` (``scales``): sectors of radius ``h - 1`` pixels
LPA_SCALES: tuple[int, ...] = (1, 2, 3, 5, 7, 11)
#: LPA order along the direction (``order``, 0 or 1)
LPA_ORDER: int = 0
#: ICI threshold ``gamma`` (confidence intervals of ``gamma`` standard deviations)
LPA_GAMMA: float = 1.5


def lpa_kernels(directions: int, scales: list[int], order: int) -> torch.Tensor:
    """(directions * len(scales), 1, 2R + 1, 2R + 1) float64 kernels, ``R = max(scales) - 1``,
    direction-major; each sums to 1 and reproduces polynomials of degree ``order`` along its
    direction (as cross-correlation kernels: output(p) = sum_q g(q) x(p + q))."""
    R = max(max(scales) - 1, 1)
    u = torch.arange(-R, R + 1, dtype=torch.float64)
    yy, xx = torch.meshgrid(u, u, indexing="ij")
    rho = torch.sqrt(yy.square() + xx.square())
    ang = torch.atan2(yy, xx)
    half = math.pi / directions + 1e-9
    out: list[torch.Tensor] = []
    for d in range(directions):
        th = 2.0 * math.pi * d / directions
        dang = torch.remainder(ang - th + math.pi, 2.0 * math.pi) - math.pi
        sector = dang.abs() <= half
        t = xx * math.cos(th) + yy * math.sin(th)  # coordinate along the direction
        for h in scales:
            w = ((sector & (rho <= h - 1 + 1e-9)) | (rho == 0)).to(torch.float64)
            if order == 0:
                g = w / w.sum()
            else:
                phi = torch.stack([torch.ones_like(t), t], 0).reshape(2, -1)  # (2, K)
                wf = w.reshape(-1)
                gram = (phi * wf) @ phi.t()
                if float(torch.linalg.det(gram)) < 1e-9:  # a one-pixel sector: the mean
                    g = w / w.sum()
                else:
                    g = (torch.linalg.solve(gram, phi * wf)[0]).reshape(w.shape)
            out.append(g)
    return torch.stack(out, 0).unsqueeze(1)


def _check(directions: int, scales: list[int], order: int, gamma: float) -> None:
    if directions < 1:
        raise ValueError(f"directions must be an int >= 1, got {directions}")
    if len(scales) < 1:
        raise ValueError("scales must be a non-empty list of increasing ints >= 1")
    prev = 0
    for h in scales:
        if h <= prev:
            raise ValueError(f"scales must be increasing ints >= 1, got {scales}")
        prev = h
    if order != 0 and order != 1:
        raise ValueError(f"order must be 0 or 1, got {order}")
    if not (gamma > 0.0 and gamma < float("inf")):
        raise ValueError(f"gamma must be a finite number > 0, got {gamma}")


def _lpa_core(
    x: torch.Tensor,
    m: torch.Tensor,
    var: torch.Tensor,
    kernels: torch.Tensor,
    directions: int,
    gamma: float,
    normalised: bool,
) -> torch.Tensor:
    """(1, 1, H, W) depth (0 at invalid pixels when ``normalised``), validity, noise variance."""
    H, W = x.shape[-2], x.shape[-1]
    R = (kernels.shape[-1] - 1) // 2
    S = kernels.shape[0] // directions
    k2 = kernels.square()
    xp = F.pad(x * m, [R, R, R, R])
    vp = F.pad(var * m, [R, R, R, R])
    if normalised:
        mp = F.pad(m, [R, R, R, R])
        den = F.conv2d(mp, kernels).clamp_min(1e-12)
        y = F.conv2d(xp, kernels) / den
        v = F.conv2d(vp, k2) / den.square()
    else:
        y = F.conv2d(F.pad(x, [R, R, R, R], mode="replicate"), kernels)
        v = F.conv2d(F.pad(var, [R, R, R, R], mode="replicate"), k2)
    y = y.reshape(directions, S, H, W)
    s = v.clamp_min(0.0).sqrt().reshape(directions, S, H, W)
    lo = torch.cummax(y - gamma * s, 1).values
    hi = torch.cummin(y + gamma * s, 1).values
    ok = (lo <= hi).to(torch.int64)
    # the adaptive scale: the last of the leading run of intersecting scales
    run = torch.cumprod(ok, 1)
    idx = (run.sum(1, keepdim=True) - 1).clamp_min(0)  # (D, 1, H, W)
    yb = torch.gather(y, 1, idx)
    vb = torch.gather(s, 1, idx).square().clamp_min(1e-30)
    w = 1.0 / vb
    return ((yb * w).sum(0) / w.sum(0)).reshape(1, 1, H, W)


def lpa_ici(
    depth: torch.Tensor,
    amplitude: torch.Tensor | None = None,
    sigma: float | torch.Tensor | None = None,
    directions: int = LPA_DIRECTIONS,
    scales: tuple[int, ...] = LPA_SCALES,
    order: int = LPA_ORDER,
    gamma: float = LPA_GAMMA,
    k: float | None = None,
    signed: bool = False,
) -> torch.Tensor:
    r"""Anisotropic LPA-ICI denoising of (B, C, H, W) depth (module docstring).

    Args:
        depth: (B, C, H, W) floating depth (channels independently).
        amplitude: optional (B, 1, H, W): validity and, without ``sigma``, the noise ``k / A``.
        sigma: noise (number, (B,) tensor, (B, 1, H, W) map, or None: estimated).
        directions: number of sector directions.
        scales: increasing scales ``h``: sectors of radius ``h - 1`` pixels.
        order: LPA order along the direction, 0 or 1.
        gamma: ICI threshold (confidence intervals of ``gamma`` standard deviations).
        k, signed: as :func:`~tof_fpn_torch.denoise.bm3d`.

    Returns:
        (B, C, H, W), dtype of ``depth``; invalid pixels unchanged.

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> step = torch.cat([torch.ones(1, 1, 32, 16), 2 * torch.ones(1, 1, 32, 16)], -1)
        >>> out = lpa_ici(step + 0.05 * torch.randn(1, 1, 32, 32, generator=g), sigma=0.05)
        >>> bool((out - step).abs().mean() < 0.02)  # smoothed, and the edge kept
        True
    """
    sc = [int(h) for h in scales]
    return _lpa_ici(
        depth,
        amplitude,
        sigma,
        directions,
        sc,
        order,
        float(gamma),
        k,
        signed,
        lpa_kernels(directions, sc, order),
        hh_kernel(torch.float64, depth.device),
    )


def _lpa_ici(
    depth: torch.Tensor,
    amplitude: torch.Tensor | None,
    sigma: float | torch.Tensor | None,
    directions: int,
    scales: list[int],
    order: int,
    gamma: float,
    k: float | None,
    signed: bool,
    kernels: torch.Tensor,
    wavelet: torch.Tensor,
) -> torch.Tensor:
    if not torch.jit.is_scripting():
        sigma = as_sigma(sigma)
    _check(directions, scales, order, gamma)
    x, valid, amp = prepare(depth, amplitude, signed)
    B, C, H, W = x.shape
    sig = noise_map(x, valid, amp, sigma, k, wavelet)
    kk = kernels.to(dtype=x.dtype, device=x.device)
    m = valid.to(x.dtype)
    out = x.clone()
    for b in range(B):
        vb = valid[b : b + 1]
        if not bool(vb.any()) or not bool((sig[b] > 0).any()):
            continue
        var = sig[b : b + 1].square()
        for c in range(C):
            d = x[b : b + 1, c : c + 1]
            if order == 0:
                d = torch.where(vb, d, torch.zeros_like(d))
                res = _lpa_core(d, m[b : b + 1], var, kk, directions, gamma, True)
            else:
                df = fill_invalid(d, vb)
                vf = fill_invalid(var, vb)
                res = _lpa_core(df, torch.ones_like(df), vf, kk, directions, gamma, False)
            out[b, c] = res[0, 0]
    return restore_invalid(out, depth, valid)


class LPAICI(Denoiser):
    r"""Anisotropic LPA-ICI denoiser (module of :func:`lpa_ici`, same parameters).

    ``forward(depth, amplitude=None, sigma=None)``; ``torch.jit.script`` compiles it. The kernels
    are a buffer built once.
    """

    def __init__(
        self,
        directions: int = LPA_DIRECTIONS,
        scales: tuple[int, ...] = LPA_SCALES,
        order: int = LPA_ORDER,
        gamma: float = LPA_GAMMA,
        k: float | None = None,
        signed: bool = False,
    ) -> None:
        super().__init__()
        for name, v in (
            ("directions", directions),
            ("order", order),
            *[("scales", h) for h in scales],
        ):
            if isinstance(v, bool) or not isinstance(v, int):
                raise ValueError(f"{name} must be ints, got {v!r}")
        sc = [int(h) for h in scales]
        _check(directions, sc, order, float(gamma))
        check_k(k)
        self.directions = directions
        self.scales = sc
        self.order = order
        self.gamma = float(gamma)
        self.k: float | None = None if k is None else float(k)
        self.signed = bool(signed)
        self.register_buffer("kernels", lpa_kernels(directions, sc, order))
        self.register_buffer("wavelet", hh_kernel(torch.float64, torch.device("cpu")))

    def extra_repr(self) -> str:
        return f"directions={self.directions}, scales={self.scales}, order={self.order}, gamma={self.gamma}"

    def forward(
        self,
        depth: torch.Tensor,
        amplitude: torch.Tensor | None = None,
        sigma: float | torch.Tensor | None = None,
    ) -> torch.Tensor:
        return _lpa_ici(
            depth,
            amplitude,
            sigma,
            self.directions,
            self.scales,
            self.order,
            self.gamma,
            self.k,
            self.signed,
            self.kernels,
            self.wavelet,
        )
