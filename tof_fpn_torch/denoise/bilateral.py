r"""Bilateral and joint (cross) bilateral filters for ToF depth, built on ``kornia.filters``.

They wrap :func:`kornia.filters.bilateral_blur` and :func:`kornia.filters.joint_bilateral_blur`
(the weights are kornia's: a Gaussian of the distance, ``sigma_space``, times a Gaussian of the
guide's difference from the centre, ``sigma_color``; ``'l1'`` colour distance, reflected borders)
and add what ToF data need and kornia lacks:

* **Invalid pixels** (:func:`~tof_fpn_torch.runtime.valid_mask`: depth NaN, inf or <= 0,
  amplitude NaN or < 0) are masked: they get weight 0 as neighbours (normalised convolution: the
  filter is run on ``[m * depth, m]`` with the same weights, ``m`` the validity, and the first
  channel divided by the second) and are returned unchanged. kornia's own functions use them as
  data: a hole at depth 0 drags its neighbours towards 0 and a NaN spreads.
* **A range sigma that follows the noise**: ``sigma_color = color * sigma(p)`` per pixel with the
  package's noise rules (:mod:`tof_fpn_torch.denoise._common`; with an amplitude and no sigma, the
  ToF law ``sigma_D = k / A``), where kornia takes one value per image. The filter is run at a few
  levels of ``sigma_color`` and interpolated per pixel (:mod:`tof_fpn_torch.denoise._levels`); an
  image with one noise level is one exact kornia call. ``sigma_color=`` (absolute) overrides it.

When every pixel is valid and the range sigma is one number per image, the result is kornia's own
function, bit for bit (tests/test_kornia_filters.py). ``Bilateral`` guides by the depth itself,
``JointBilateral`` by the amplitude (required), with a range sigma in amplitude units: ``color``
times the amplitude's noise, estimated per image (wavelet MAD) unless ``sigma_color`` is given; the
depth noise ``sigma`` is then not used.

TorchScript: not supported -- kornia's filters are Python functions with Python-only checks
(``KORNIA_CHECK``) and are not scriptable. ``torch.jit.trace`` runs but records the data-dependent
choices of the traced frame (holes or none, the number of levels), so it is no general export.
"""

from __future__ import annotations

import torch
from kornia.filters import bilateral_blur, joint_bilateral_blur

from ..runtime.noise import hh_kernel, wavelet_sigma
from ._common import Denoiser, as_sigma, check_k, check_window, noise_map, prepare, restore_invalid
from ._levels import LEVEL_RATIO, MAX_LEVELS, blend, check_levels, levels

__all__ = [
    "BILATERAL_COLOR",
    "BILATERAL_KERNEL_SIZE",
    "BILATERAL_SIGMA_SPACE",
    "Bilateral",
    "JointBilateral",
    "bilateral",
    "joint_bilateral",
]

# Defaults of bilateral / joint_bilateral and their modules (written once; see the docstrings)
#: window side ``kernel_size`` (odd)
BILATERAL_KERNEL_SIZE: int = 9
#: spatial standard deviation ``sigma_space`` (pixels)
BILATERAL_SIGMA_SPACE: float = 3.0
#: range standard deviation in noise standard deviations (``color``)
BILATERAL_COLOR: float = 2.0


def _check(kernel_size: int, sigma_space: float, color: float, sigma_color: float | None) -> None:
    if isinstance(kernel_size, bool) or not isinstance(kernel_size, int) or kernel_size < 1:
        raise ValueError(f"kernel_size must be an odd int >= 1, got {kernel_size!r}")
    if kernel_size % 2 == 0:
        raise ValueError(f"kernel_size must be odd, got {kernel_size}")
    if not (sigma_space > 0 and sigma_space < float("inf")):
        raise ValueError(f"sigma_space must be a finite number > 0, got {sigma_space!r}")
    if not (color > 0 and color < float("inf")):
        raise ValueError(f"color must be a finite number > 0, got {color!r}")
    if sigma_color is not None and not (sigma_color > 0 and sigma_color < float("inf")):
        raise ValueError(f"sigma_color must be None or a finite number > 0, got {sigma_color!r}")


def _filter(
    x: torch.Tensor,
    valid: torch.Tensor,
    guide: torch.Tensor | None,
    rsig: torch.Tensor,
    kernel_size: int,
    sigma_space: float,
    ratio: float,
    max_levels: int,
    fixed: float | None,
) -> torch.Tensor:
    """Masked (joint) bilateral of ``x`` with the per-pixel range sigma ``rsig`` (B, 1, H, W), or
    the number ``fixed`` (passed to kornia as it is)."""
    B, C, H, W = x.shape
    lv = levels(rsig, valid, ratio, max_levels)  # (B, L)
    L = lv.shape[1]
    space = (sigma_space, sigma_space)
    rep: float | torch.Tensor = lv.reshape(-1) if fixed is None else fixed
    every = bool(valid.all())
    if every:
        inp = x
    else:
        m = valid.to(x.dtype)
        inp = torch.cat([torch.where(valid, x, torch.zeros_like(x)), m], 1)
    g = guide
    if g is None and not every:
        g = torch.where(valid, x, torch.zeros_like(x))
    inp = inp.repeat_interleave(L, 0)
    if g is None:
        out = bilateral_blur(inp, kernel_size, rep, space)
    else:
        out = joint_bilateral_blur(inp, g.repeat_interleave(L, 0), kernel_size, rep, space)
    if not every:
        out = out[:, :C] / out[:, C:].clamp_min(1e-30)
    return blend(out.reshape(B, L, C, H, W), lv, rsig)


def _range_sigma(sig: torch.Tensor, valid: torch.Tensor, color: float) -> torch.Tensor:
    """``color * sig``; pixels without noise get a range sigma 1e-6 of the image's largest (only
    equal neighbours count: left as they are)."""
    r = color * sig
    top = torch.where(valid, r, torch.zeros_like(r)).flatten(1).amax(1).reshape(-1, 1, 1, 1)
    return torch.maximum(r, 1e-6 * top)


def _bilateral(
    depth: torch.Tensor,
    amplitude: torch.Tensor | None,
    sigma: float | torch.Tensor | None,
    kernel_size: int,
    sigma_space: float,
    color: float,
    sigma_color: float | None,
    k: float | None,
    signed: bool,
    ratio: float,
    max_levels: int,
    joint: bool,
) -> torch.Tensor:
    sigma = as_sigma(sigma)
    _check(kernel_size, sigma_space, color, sigma_color)
    if joint and amplitude is None:
        raise ValueError("JointBilateral needs the amplitude (the guide)")
    x, valid, amp = prepare(depth, amplitude, signed)
    B, C, H, W = x.shape
    if B == 0 or H == 0 or W == 0:
        return depth.clone()
    check_window(H, W, kernel_size, "bilateral")
    wavelet = hh_kernel(x.dtype, x.device)
    guide: torch.Tensor | None = None
    if joint:
        assert amp is not None
        guide = torch.where(valid, amp, torch.zeros_like(amp))
        if sigma_color is None:
            sa = wavelet_sigma(guide, valid, wavelet).reshape(B, 1, 1, 1)
            rsig = (color * sa).expand(B, 1, H, W)
        else:
            rsig = torch.full((B, 1, H, W), sigma_color, dtype=x.dtype, device=x.device)
        live = (rsig.flatten(1).amax(1) > 0) & valid.flatten(1).any(1)
        if sigma is not None:  # checked as every denoiser's; 0 (no noise) leaves the image
            sig = noise_map(x, valid, amp, sigma, k, wavelet)
            live = live & (sig.flatten(1).amax(1) > 0)
    else:
        if sigma_color is None:
            sig = noise_map(x, valid, amp, sigma, k, wavelet)
            live = (sig.flatten(1).amax(1) > 0) & valid.flatten(1).any(1)
            rsig = _range_sigma(sig, valid, color)
        else:
            rsig = torch.full((B, 1, H, W), sigma_color, dtype=x.dtype, device=x.device)
            live = valid.flatten(1).any(1)
    out = x.clone()
    idx = torch.nonzero(live).flatten()
    if idx.numel() > 0:
        sel = _filter(
            x[idx],
            valid[idx],
            None if guide is None else guide[idx],
            rsig[idx].clamp_min(1e-30),
            kernel_size,
            sigma_space,
            ratio,
            max_levels,
            sigma_color,
        )
        out[idx] = sel
    return restore_invalid(out, depth, valid)


def bilateral(
    depth: torch.Tensor,
    amplitude: torch.Tensor | None = None,
    sigma: float | torch.Tensor | None = None,
    kernel_size: int = BILATERAL_KERNEL_SIZE,
    sigma_space: float = BILATERAL_SIGMA_SPACE,
    color: float = BILATERAL_COLOR,
    sigma_color: float | None = None,
    k: float | None = None,
    signed: bool = False,
    ratio: float = LEVEL_RATIO,
    max_levels: int = MAX_LEVELS,
) -> torch.Tensor:
    r"""Bilateral filter of (B, C, H, W) depth (kornia's, masked, range sigma following the noise).

    Args:
        depth: (B, C, H, W) floating depth.
        amplitude: optional (B, 1, H, W): validity and, without ``sigma``, the noise ``k / A``.
        sigma: depth noise (number, (B,) tensor, (B, 1, H, W) map, or None: estimated).
        kernel_size: odd window side (kornia ``kernel_size``).
        sigma_space: spatial Gaussian standard deviation, pixels (kornia ``sigma_space``).
        color: range sigma in units of the noise: ``sigma_color = color * sigma(p)``.
        sigma_color: a fixed range sigma in depth units instead (kornia's behaviour).
        k: ``sigma = k / A`` constant (None: estimated).
        signed: the data are a signed image, not depth (only NaN / inf invalid).
        ratio, max_levels: spacing and number of the range-sigma levels (module docstring).

    Returns:
        (B, C, H, W) in the dtype of ``depth``; invalid pixels unchanged; an image without noise
        (sigma 0) or without valid pixels unchanged.

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> d = 2.0 + 0.01 * torch.randn(1, 1, 16, 16, generator=g)
        >>> d[0, 0, 5, 5] = 0.0  # a hole: it stays 0 and does not pull its neighbours down
        >>> out = bilateral(d, sigma_color=5.0)  # a range sigma far above the 2 m jump
        >>> float(out[0, 0, 5, 5]), bool(out[0, 0, 4:7, 4:7].sum() - out[0, 0, 5, 5] > 15.9)
        (0.0, True)
    """
    return _bilateral(
        depth,
        amplitude,
        sigma,
        kernel_size,
        float(sigma_space),
        float(color),
        None if sigma_color is None else float(sigma_color),
        k,
        signed,
        float(ratio),
        int(max_levels),
        False,
    )


def joint_bilateral(
    depth: torch.Tensor,
    amplitude: torch.Tensor,
    sigma: float | torch.Tensor | None = None,
    kernel_size: int = BILATERAL_KERNEL_SIZE,
    sigma_space: float = BILATERAL_SIGMA_SPACE,
    color: float = BILATERAL_COLOR,
    sigma_color: float | None = None,
    signed: bool = False,
) -> torch.Tensor:
    r"""Joint bilateral filter of depth guided by the amplitude (kornia's, masked).

    The range kernel compares amplitudes: ``sigma_color`` in amplitude units, default ``color``
    times the amplitude's noise (wavelet MAD estimate per image). ``sigma`` (depth noise) does not
    set the range kernel; a given ``sigma`` is checked as every denoiser's (finite, ``>= 0``) and
    ``sigma = 0`` (no noise) returns that image unchanged, as every denoiser.
    """
    return _bilateral(
        depth,
        amplitude,
        sigma,
        kernel_size,
        float(sigma_space),
        float(color),
        None if sigma_color is None else float(sigma_color),
        None,
        signed,
        1.25,
        1,
        True,
    )


class Bilateral(Denoiser):
    """Bilateral filter (kornia) with masked holes and a range sigma following the noise.

    Module of :func:`bilateral` (same parameters); ``forward(depth, amplitude=None, sigma=None)``.
    Not scriptable (kornia's functions are not); see the module docstring.
    """

    def __init__(
        self,
        kernel_size: int = BILATERAL_KERNEL_SIZE,
        sigma_space: float = BILATERAL_SIGMA_SPACE,
        color: float = BILATERAL_COLOR,
        sigma_color: float | None = None,
        k: float | None = None,
        signed: bool = False,
        ratio: float = LEVEL_RATIO,
        max_levels: int = MAX_LEVELS,
    ) -> None:
        super().__init__()
        _check(kernel_size, sigma_space, color, sigma_color)
        check_levels(ratio, max_levels)
        check_k(k)
        self.kernel_size, self.sigma_space, self.color = kernel_size, float(sigma_space), color
        self.sigma_color, self.k, self.signed = sigma_color, k, signed
        self.ratio, self.max_levels = float(ratio), int(max_levels)

    def forward(self, depth, amplitude=None, sigma=None):
        return bilateral(
            depth,
            amplitude,
            sigma,
            self.kernel_size,
            self.sigma_space,
            self.color,
            self.sigma_color,
            self.k,
            self.signed,
            self.ratio,
            self.max_levels,
        )


class JointBilateral(Denoiser):
    """Joint bilateral filter (kornia) of depth guided by the amplitude, with masked holes.

    Module of :func:`joint_bilateral`; ``forward(depth, amplitude, sigma=None)`` (the amplitude is
    required; ``sigma`` is not used). Not scriptable (kornia); see the module docstring.
    """

    def __init__(
        self,
        kernel_size: int = BILATERAL_KERNEL_SIZE,
        sigma_space: float = BILATERAL_SIGMA_SPACE,
        color: float = BILATERAL_COLOR,
        sigma_color: float | None = None,
        signed: bool = False,
    ) -> None:
        super().__init__()
        _check(kernel_size, sigma_space, color, sigma_color)
        self.kernel_size, self.sigma_space, self.color = kernel_size, float(sigma_space), color
        self.sigma_color, self.signed = sigma_color, signed

    def forward(self, depth, amplitude=None, sigma=None):
        if amplitude is None:
            raise ValueError("JointBilateral needs the amplitude (the guide)")
        return joint_bilateral(
            depth,
            amplitude,
            sigma,
            self.kernel_size,
            self.sigma_space,
            self.color,
            self.sigma_color,
            self.signed,
        )
