r"""Non-local means (Buades, Coll, Morel, CVPR 2005) for depth maps: batched torch, TorchScript.

Weights
-------
For a pixel ``p``, an offset ``t`` in the search window ``|t_y|, |t_x| <= d`` (``patch_distance``)
and square patches of side ``s`` (``patch_size``, odd), the mean squared patch difference over the
``s x s`` patch and the ``C`` channels is ``m(p, t) = mean_{u, c} (x_c(p+u) - x_c(p+t+u))^2`` and::

    w(p, t) = exp(-max(m - 2 sigma^2, 0) / (h sigma)^2)            (constant sigma)
    out(p)  = sum_t w(p, t) x(p + t) / sum_t w(p, t)               (t = 0 has weight 1)

This is the uniform-patch ("box") NLM of scikit-image's ``fast_mode=True`` with its noise-variance
subtraction (``sigma`` given), ``h`` there equal to ``h * sigma`` here: ``h`` is relative to the
noise level, ``0.8`` as skimage recommends for this variant. Borders are reflected (``numpy``
``reflect``), the window is the full ``(2d + 1)^2`` square (OpenCV's ``searchWindowSize = 2d + 1``).
scikit-image's fast mode differs in three implementation details that we do not copy: its
integral image sums an ``(s - 1) x (s - 1)`` box anchored off-centre (but divides by ``s^2``),
it sets weights with ``m' > 5`` to 0, and it uses an approximate ``exp``. On natural images our
PSNR is equal or higher; on piecewise-planar depth skimage's smaller effective patch scores up to
~0.8 dB higher (``docs/denoise.md``). ``kernel='gaussian'`` weighs the patch like skimage's
``fast_mode=False`` (Buades' original) and matches its PSNR within 0.1 dB.

Per-pixel noise (ToF, eq. 2 of Georgiev et al., IEEE SAS 2015)
---------------------------------------------------------------
With a noise map ``sigma(p)`` (given, or ``k / A(p)`` from the amplitude) the expected mean squared
difference of two noise-only patches is ``S(p, t) = V(p) + V(p + t)`` with ``V`` the patch mean of
``sigma^2``, and::

    w(p, t) = exp(-(2 / h^2) max(m / S - 1, 0))

which is symmetric in ``(p, p + t)`` and equals the constant-sigma formula when ``sigma`` is
constant (then ``S = 2 sigma^2``).

Invalid depth
-------------
Pixels that fail the package's validity rule (:func:`~tof_fpn_torch.runtime.valid_mask`: depth
NaN, inf or <= 0, amplitude NaN, inf or negative; with ``signed=True`` only NaN and inf, for data
that are not depth) are invalid: ``m`` averages only pixel pairs valid in both patches, an invalid
pixel never contributes a value, and invalid pixels are returned unchanged. A valid pixel with
``A = 0`` (no signal) gets the noise level of ``A`` =
:data:`~tof_fpn_torch.constants.NLM_AMPLITUDE_FLOOR` times the image's
median amplitude: large, but finite.

Implementation: :mod:`tof_fpn_torch.denoise.nlm_core`.
"""

from __future__ import annotations

import math

import torch

from .. import constants as K
from ..runtime._checks import check_image
from ..runtime.noise import hh_kernel, wavelet_noise_k, wavelet_sigma
from ..runtime.validity import valid_mask
from ._common import Denoiser, amplitude_floor, as_sigma, check_sigma_tensor
from .nlm_core import nlm_core, patch_taps

__all__ = [
    "NLM_H",
    "NLM_KERNEL",
    "NLM_PATCH_DISTANCE",
    "NLM_PATCH_SIZE",
    "NonLocalMeans",
    "non_local_means",
]

# Defaults of non_local_means and NonLocalMeans (written once; see the docstrings)
#: odd patch side ``patch_size``
NLM_PATCH_SIZE: int = 7
#: search radius ``patch_distance``
NLM_PATCH_DISTANCE: int = 10
#: filtering parameter ``h`` relative to the noise level (skimage's recommendation for box NLM)
NLM_H: float = 0.8
#: patch weighting ``kernel``
NLM_KERNEL: str = "box"


def _check_params(
    patch_size: int, patch_distance: int, h: float, k: float | None, kernel: str
) -> None:
    if kernel != "box" and kernel != "gaussian":
        raise ValueError(f"kernel must be 'box' or 'gaussian', got '{kernel}'")
    if patch_size < 1 or patch_size % 2 == 0:
        raise ValueError(f"patch_size must be an odd integer >= 1, got {patch_size}")
    if patch_distance < 0:
        raise ValueError(f"patch_distance must be an integer >= 0, got {patch_distance}")
    if not (h > 0.0 and h < float("inf")):
        raise ValueError(f"h must be a finite number > 0 (relative to sigma), got {h}")
    if k is not None:
        if not (k > 0.0 and k < float("inf")):
            raise ValueError(f"k must be None (estimate it) or a finite number > 0, got {k}")


def non_local_means(
    depth: torch.Tensor,
    amplitude: torch.Tensor | None = None,
    sigma: float | torch.Tensor | None = None,
    patch_size: int = NLM_PATCH_SIZE,
    patch_distance: int = NLM_PATCH_DISTANCE,
    h: float = NLM_H,
    k: float | None = None,
    signed: bool = False,
    kernel: str = NLM_KERNEL,
) -> torch.Tensor:
    r"""Non-local means denoising of a batch of depth maps (Buades et al., CVPR 2005).

    Args:
        depth: (B, C, H, W) floating depth. ``C > 1`` is a vector-valued image: one set of
            weights from the distance averaged over channels, applied to every channel
            (scikit-image's ``channel_axis`` behaviour); a pixel is invalid if any channel is.
        amplitude: optional (B, 1, H, W) amplitude ``A``; without ``sigma`` it sets the noise
            map ``sigma = k / A`` (eq. 2 of Georgiev et al. 2015); with ``sigma`` (which then
            sets the noise, as for every denoiser of the package) only its validity rule is
            used. Pixels with ``A < 0`` or non-finite ``A`` are invalid.
        sigma: noise standard deviation in depth units: a float, a 0-d or (B,) tensor (one per
            image), a (B, 1, H, W) map, or None to estimate it per image (wavelet MAD, see
            :func:`tof_fpn_torch.denoise.estimate_sigma`; mean over channels).
        patch_size: odd side ``s`` of the square patches.
        patch_distance: search radius ``d``: offsets with ``|t_y|, |t_x| <= d``
            (a ``2d + 1`` window).
        h: filtering parameter relative to ``sigma`` (skimage's ``h`` is ``h * sigma``).
        k: noise constant of ``sigma = k / A`` when ``amplitude`` is given; None estimates it
            from the data (:func:`tof_fpn_torch.denoise.estimate_noise_k`, mean over channels).
        signed: ``depth`` is not depth but a signed image (e.g. a natural image): only NaN and inf
            are invalid, zeros and negative values are data.
        kernel: patch weighting, ``'box'`` (uniform, as skimage ``fast_mode=True``; fastest, and
            the better one on piecewise-planar depth) or ``'gaussian'`` (skimage
            ``fast_mode=False``, Buades' original; better on textured natural images).

    Returns:
        (B, C, H, W) denoised depth, dtype of ``depth`` (float16/bfloat16 are computed in float32);
        invalid pixels are returned unchanged. Not differentiable (no autograd graph).

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> clean = torch.linspace(1.0, 2.0, 64).repeat(1, 1, 64, 1)
        >>> noisy = clean + 0.05 * torch.randn(1, 1, 64, 64, generator=g)
        >>> out = non_local_means(noisy, sigma=0.05)
        >>> bool((out - clean).abs().mean() < 0.5 * (noisy - clean).abs().mean())
        True
    """
    return _non_local_means(
        depth,
        amplitude,
        sigma,
        patch_size,
        patch_distance,
        h,
        k,
        signed,
        kernel,
        hh_kernel(torch.float64, depth.device),
    )


def _non_local_means(
    depth: torch.Tensor,
    amplitude: torch.Tensor | None,
    sigma: float | torch.Tensor | None,
    patch_size: int,
    patch_distance: int,
    h: float,
    k: float | None,
    signed: bool,
    kernel: str,
    wavelet: torch.Tensor,
) -> torch.Tensor:
    """:func:`non_local_means` with the (1, 1, 4, 4) ``db2`` detail kernel passed in."""
    check_image(depth, "depth")
    if not torch.jit.is_scripting():
        sigma = as_sigma(sigma)
    _check_params(patch_size, patch_distance, h, k, kernel)
    B, C, H, W = depth.shape
    if H < 1 or W < 1:
        raise ValueError(f"depth must have H, W >= 1, got shape {list(depth.shape)}")
    work_dtype = torch.float64 if depth.dtype == torch.float64 else torch.float32
    x = depth.detach().to(work_dtype)
    valid = valid_mask(x, signed=signed).all(dim=1, keepdim=True)
    amp = torch.empty(0)
    if amplitude is not None:
        check_image(amplitude, "amplitude", 1)
        if amplitude.shape[0] != B or amplitude.shape[2:] != depth.shape[2:]:
            raise ValueError(
                f"amplitude must have shape (B, 1, H, W) = {[B, 1, H, W]}, "
                f"got {list(amplitude.shape)}"
            )
        amp = amplitude.detach().to(device=x.device, dtype=work_dtype)
        valid = valid & valid_mask(x[:, :1], amp, signed=True)  # amplitude part of the rule
    if B == 0:
        return depth.clone()
    if patch_distance == 0:
        return depth.detach().clone()
    all_valid = bool(valid.all())
    x = torch.where(valid, x, torch.zeros_like(x))
    wkernel = wavelet.to(device=x.device, dtype=work_dtype)
    half_var, sig_img = _noise(x, valid, amp, amplitude is not None, sigma, k, wkernel)
    scale = _input_scale(x, half_var, sig_img, all_valid, patch_size, h)
    out = _chunks(x, valid, all_valid, scale, half_var, patch_size, patch_distance, h, kernel)
    out = torch.where(valid, out, depth.detach().to(work_dtype))
    return out.to(depth.dtype)


def _noise(
    x: torch.Tensor,
    valid: torch.Tensor,
    amp: torch.Tensor,
    has_amp: bool,
    sigma: float | torch.Tensor | None,
    k: float | None,
    wkernel: torch.Tensor,
) -> tuple[torch.Tensor | None, torch.Tensor]:
    """``(half_var, sig_img)``: the noise map's ``sigma^2 / 2`` (B, 1, H, W) where the noise
    varies per pixel (``k / A``, or a given map), else None and the per-image level (B, 1, 1, 1)
    (estimated, or given); see the module docstring."""
    B, C, H, W = x.shape
    valid_c = valid.expand(B, C, H, W)
    half_var: torch.Tensor | None = None
    sig_img = torch.zeros(B, 1, 1, 1, dtype=x.dtype, device=x.device)
    if has_amp and sigma is None:
        if k is None:
            kk = wavelet_noise_k(x, amp, valid_c, wkernel).mean(dim=1)
        else:
            kk = torch.full([B], k, dtype=x.dtype, device=x.device)
        safe = torch.where(valid, amp.clamp_min(amplitude_floor(amp, valid)), torch.ones_like(amp))
        sig_map = kk.view(B, 1, 1, 1) / safe
        half_var = torch.where(valid, 0.5 * sig_map * sig_map, torch.zeros_like(sig_map))
    elif sigma is None:
        sig_img = wavelet_sigma(x, valid_c, wkernel).mean(dim=1).view(B, 1, 1, 1)
    elif isinstance(sigma, float):
        if not (sigma >= 0.0 and sigma < float("inf")):
            raise ValueError(f"sigma must be a finite number >= 0, got {sigma}")
        sig_img = torch.full([B, 1, 1, 1], sigma, dtype=x.dtype, device=x.device)
    else:
        check_sigma_tensor(sigma, B, H, W)
        sg = sigma.detach().to(device=x.device, dtype=x.dtype)
        if sg.dim() == 4 and (sg.shape[2] != 1 or sg.shape[3] != 1):
            sg = sg.expand(B, 1, H, W)
            bad = valid & ~(torch.isfinite(sg) & (sg >= 0))
            if bool(bad.any()):
                raise ValueError(
                    "sigma map must be finite and >= 0 at every valid pixel, got "
                    f"{int(bad.sum())} bad value(s)"
                )
            sg = torch.where(valid, sg, torch.zeros_like(sg))
            half_var = 0.5 * sg * sg
        else:
            sg = sg.reshape(-1).expand(B).reshape(B, 1, 1, 1)
            if not bool((torch.isfinite(sg) & (sg >= 0)).all()):
                raise ValueError(f"sigma must be finite and >= 0, got minimum {float(sg.min())}")
            sig_img = sg
    return half_var, sig_img


def _input_scale(
    x: torch.Tensor,
    half_var: torch.Tensor | None,
    sig_img: torch.Tensor,
    all_valid: bool,
    s: int,
    h: float,
) -> torch.Tensor:
    """(B, 1, 1, 1) ``sqrt(log2 e) / (h sigma sqrt(C))`` (times ``1 / s`` without holes), the
    factor :func:`~tof_fpn_torch.denoise.nlm_core.nlm_core` folds into its input (without the
    ``1 / sigma`` where a noise map sets the weights)."""
    B, C = x.shape[0], x.shape[1]
    inv_s = 1.0 if not all_valid else 1.0 / s
    if half_var is None:
        # a zero noise level keeps only identical patches; floor it to stay finite
        amax = x.abs().amax(dim=(1, 2, 3)).view(B, 1, 1, 1)
        sig_img = torch.maximum(sig_img, 1e-7 * amax + 1e-30)
        return math.sqrt(K.LOG2_E) * inv_s / (h * math.sqrt(C)) / sig_img
    return torch.full(
        [B, 1, 1, 1],
        math.sqrt(K.LOG2_E) * inv_s / (h * math.sqrt(C)),
        dtype=x.dtype,
        device=x.device,
    )


def _chunks(
    x: torch.Tensor,
    valid: torch.Tensor,
    all_valid: bool,
    scale: torch.Tensor,
    half_var: torch.Tensor | None,
    s: int,
    d: int,
    h: float,
    kernel: str,
) -> torch.Tensor:
    """:func:`~tof_fpn_torch.denoise.nlm_core.nlm_core` over chunks of the batch (at most ~2M
    padded values each)."""
    B, C, H, W = x.shape
    taps = patch_taps(s, kernel)
    per_image = C * (H + 2 * d + s) * (W + 2 * d + s)
    chunk = max(1, 2097152 // per_image)
    outs: list[torch.Tensor] = []
    for b0 in range(0, B, chunk):
        b1 = min(B, b0 + chunk)
        vmask: torch.Tensor | None = None
        if not all_valid:
            vmask = valid[b0:b1].to(x.dtype)
        hv: torch.Tensor | None = None
        if half_var is not None:
            hv = half_var[b0:b1]
        outs.append(nlm_core(x[b0:b1], vmask, scale[b0:b1], hv, s, d, h, taps))
    return torch.cat(outs, 0)


class NonLocalMeans(Denoiser):
    r"""Non-local means denoiser for (B, C, H, W) depth (thin module over :func:`non_local_means`).

    Args:
        patch_size: odd patch side ``s`` (skimage ``patch_size``, OpenCV ``templateWindowSize``).
        patch_distance: search radius ``d`` (skimage ``patch_distance``; OpenCV
            ``searchWindowSize = 2d + 1``).
        h: filtering parameter relative to the noise level (skimage ``h = h * sigma``).
        k: constant of the ToF noise law ``sigma = k / A`` used when ``forward`` gets an
            amplitude; None estimates it per image.
        signed: the input is a signed image, not depth (only NaN / inf invalid).
        kernel: patch weighting, ``'box'`` or ``'gaussian'`` (see :func:`non_local_means`).

    Shape:
        - depth: (B, C, H, W) float; amplitude: (B, 1, H, W); sigma: float, (B,) or (B, 1, H, W).
        - Output: (B, C, H, W), same dtype; invalid pixels unchanged.

    Example:
        >>> nlm = NonLocalMeans(patch_size=5, patch_distance=5)
        >>> nlm(torch.ones(2, 1, 16, 16), sigma=0.1).shape
        torch.Size([2, 1, 16, 16])
    """

    #: read by :func:`tof_fpn_torch.export.export_onnx`, which refuses the module with this reason
    onnx_unsupported = (
        "non-local means takes data-dependent branches (the shortcut for frames without holes, "
        "the batch chunking), which torch.export cannot trace: export it with TorchScript"
    )

    def __init__(
        self,
        patch_size: int = NLM_PATCH_SIZE,
        patch_distance: int = NLM_PATCH_DISTANCE,
        h: float = NLM_H,
        k: float | None = None,
        signed: bool = False,
        kernel: str = NLM_KERNEL,
    ) -> None:
        super().__init__()
        for name, v in (("patch_size", patch_size), ("patch_distance", patch_distance)):
            if isinstance(v, bool) or not isinstance(v, int):
                raise ValueError(f"{name} must be an int, got {v!r}")
        for name, v in (("h", h), ("k", k)):
            if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))):
                raise ValueError(f"{name} must be a real number, got {v!r}")
        if not isinstance(signed, bool):
            raise ValueError(f"signed must be a bool, got {signed!r}")
        kf: float | None = None if k is None else float(k)
        _check_params(patch_size, patch_distance, float(h), kf, kernel)
        self.patch_size = patch_size
        self.patch_distance = patch_distance
        self.h = float(h)
        self.k = kf
        self.signed = signed
        self.kernel = kernel
        #: db2 diagonal-detail kernel of the noise estimators (fixed coefficients)
        self.register_buffer("wavelet", hh_kernel(torch.float64, torch.device("cpu")))

    def extra_repr(self) -> str:
        return (
            f"patch_size={self.patch_size}, patch_distance={self.patch_distance}, h={self.h}, "
            f"k={self.k}, signed={self.signed}, kernel={self.kernel!r}"
        )

    def forward(
        self,
        depth: torch.Tensor,
        amplitude: torch.Tensor | None = None,
        sigma: float | torch.Tensor | None = None,
    ) -> torch.Tensor:
        return _non_local_means(
            depth,
            amplitude,
            sigma,
            self.patch_size,
            self.patch_distance,
            self.h,
            self.k,
            self.signed,
            self.kernel,
            self.wavelet,
        )
