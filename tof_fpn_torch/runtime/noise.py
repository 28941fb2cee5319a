r"""Robust noise estimation: the one home of every noise scale of the package (torch only,
TorchScript-clean).

Three estimators, each where its kind of robustness is needed:

* **Wavelet MAD** (:func:`estimate_sigma`, :func:`estimate_noise_k`; :func:`wavelet_sigma` and
  :func:`wavelet_noise_k` are the same without argument checks, for callers that hold the
  :func:`hh_kernel` as a buffer): the noise level of a depth map from its finest diagonal wavelet
  band (the denoisers, the builders, ``tof-fpn clean``'s record). Described below.
* **Clipped mean** (:func:`clipped_scale`): ``sqrt(pi / 2)`` times the mean ``|x|``, refined three
  times over the values within 3 of its sigmas, de-biased for the clipping. Sums only (no sort), so
  it exports; unlike a MAD it does not collapse to 0 on two-valued data (a stripe at ``pi``). The
  stripe gate (:mod:`.gate`) and the stripe detection (:mod:`tof_fpn_torch.analysis.stripes`).
* **Noise law from facets** (:func:`facet_noise`): a per-pixel map ``sigma(A)`` from the
  residuals of local 3 x 3 plane fits, the law ``log sigma^2 = c - gamma log A`` fitted per frame
  (the flying-pixel and temporal stages). Described at the end.
* **Clipped RMS** (:func:`clipped_rms_scale`): a MAD start refined by clipped-RMS iterations
  de-biased for the clipping (:func:`scale_moment`), for one channel or the magnitude of two (a
  complex residual); depth quantised to whole millimetres, where the MAD can be 0, is measured
  right. The destriper (:mod:`._destripe_core`) and the complex-domain calibration.

:func:`mad_to_sigma` turns a median of ``|e|`` into the standard deviation of each of the
``channels`` Gaussian components of ``e``.

Gaussian noise level (as ``skimage.restoration.estimate_sigma``)
----------------------------------------------------------------
One level of the 2-D Daubechies-2 (``db2``) wavelet transform; the diagonal detail band ``HH``
(high-pass along rows and columns, stride 2) is almost free of signal on smooth and on planar
surfaces (``db2`` has two vanishing moments, so it annihilates planes; only edges leave large
coefficients). For i.i.d. noise of standard deviation ``sigma`` the orthonormal transform gives
``HH ~ N(0, sigma^2)`` and the robust estimate is the median absolute deviation (Donoho and
Johnstone, Biometrika 81, 1994)::

    sigma_hat = median(|HH|) / Phi^-1(3/4),      Phi^-1(3/4) = 0.6744897...

As in scikit-image, exact zeros are dropped before the median (quantised flat areas). Unlike it,
only "valid" coefficients are used: those whose 4 x 4 support lies inside the image and touches no
invalid pixel (NaN, +-inf, or a pixel the caller marks invalid, e.g. depth 0). ``pywt`` extends the
borders symmetrically and keeps two more coefficients per axis; on frames of a few dozen pixels
and more the two medians agree to well under 1 % (``tests/test_nlm.py`` compares them).

Amplitude-dependent noise (eq. 2 of Georgiev et al., IEEE SAS 2015)
-------------------------------------------------------------------
ToF depth noise follows ``sigma_D = k / A`` (eq. 2: ``sigma_D^2 ~ lambda / A^2``, so
``k = sqrt(lambda)`` in the units of depth times amplitude). A detail coefficient is a linear
combination ``d = sum_j g_j D_j`` of 16 pixels with the ``HH`` taps ``g``; with independent noise
its standard deviation is ``k * s`` with ``s = sqrt(sum_j g_j^2 / A_j^2)``, so ``d / s ~ N(0, k^2)``
exactly, whatever the amplitudes, and::

    k_hat = median(|d| / s) / Phi^-1(3/4)

over the valid coefficients (pixels with ``A <= 0`` or non-finite ``A`` are invalid).

The noise law per pixel (:func:`facet_noise`)
---------------------------------------------
Shot noise gives ``sigma_D^2 ~ 1 / A``, read noise ``~ 1 / A^2`` (eq. 2); a camera sits in
between. The residual variance ``v`` of the 3 x 3 plane fit around a pixel (6 degrees of
freedom, :mod:`._facets`) estimates ``sigma^2`` there without bias on planes and slopes; windows
across a depth edge are far above it. Per frame, ``log v = c - gamma log A`` is fitted by least
squares over the pixels with ``v > 0`` and ``A > 0``, three times, each time keeping the residuals
within 2 (natural-log units; the log of a chi-square with 6 degrees of freedom over 6 has a
standard deviation of 0.6, so 2 keeps the noise and drops the edges), ``gamma`` clamped to
``[0, 2]``. The map is ``sigma = exp((c - gamma log A + 0.1758) / 2)``, ``0.1758 = log 3 - psi(3)``
de-biasing the mean of the log; without an amplitude ``gamma = 0`` (one level per frame). Sums
only: it scripts and exports.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from .. import constants as K
from ._checks import check_image
from ._facets import plane_fit

__all__ = [
    "clipped_rms_scale",
    "clipped_scale",
    "estimate_noise_k",
    "estimate_sigma",
    "facet_noise",
    "hh_kernel",
    "mad_to_sigma",
    "scale_moment",
    "wavelet_noise_k",
    "wavelet_sigma",
]


def hh_kernel(dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """The (1, 1, 4, 4) ``db2`` diagonal-detail kernel for ``conv2d`` (cross-correlation).

    ``pywt`` convolves with ``dec_hi`` and keeps odd full-convolution samples; as a
    cross-correlation with stride 2 that is the outer product of the *reversed* filter.
    """
    g = torch.tensor(K.DB2_DEC_HI, dtype=torch.float64).flip(0)
    return torch.outer(g, g).to(dtype=dtype, device=device).reshape(1, 1, 4, 4)


def _median_abs(values: torch.Tensor, keep: torch.Tensor) -> torch.Tensor:
    """Per (b, c) median of ``|values|`` over ``keep`` (lower and upper middle averaged, as
    ``numpy.median``); 0 where nothing is kept. ``values``/``keep``: (B, C, h, w)."""
    B, C = values.shape[0], values.shape[1]
    out = torch.zeros(B, C, dtype=values.dtype, device=values.device)
    flat_v = values.abs().reshape(B, C, -1)
    flat_k = keep.reshape(B, C, -1)
    for b in range(B):
        for c in range(C):
            v = flat_v[b, c][flat_k[b, c]]
            n = v.numel()
            if n > 0:
                v = torch.sort(v).values
                out[b, c] = 0.5 * (v[(n - 1) // 2] + v[n // 2])
    return out


def _valid_coefficients(
    x: torch.Tensor, valid: torch.Tensor | None, kernel: torch.Tensor
) -> torch.Tensor:
    """(B, C, h, w) bool: HH coefficients whose 4 x 4 support is finite and valid."""
    bad = ~torch.isfinite(x)
    if valid is not None:
        bad = bad | ~valid
    ones = torch.ones_like(kernel)
    B, C, H, W = x.shape
    touched = F.conv2d(bad.to(kernel.dtype).reshape(B * C, 1, H, W), ones, stride=2)
    return (touched == 0).reshape(B, C, touched.shape[-2], touched.shape[-1])


def _detail(x: torch.Tensor, kernel: torch.Tensor) -> torch.Tensor:
    B, C, H, W = x.shape
    clean = torch.where(torch.isfinite(x), x, torch.zeros_like(x))
    d = F.conv2d(clean.reshape(B * C, 1, H, W), kernel, stride=2)
    return d.reshape(B, C, d.shape[-2], d.shape[-1])


def _check_valid(valid: torch.Tensor | None, x: torch.Tensor) -> None:
    if valid is not None:
        if valid.dtype != torch.bool:
            raise ValueError(f"valid must be a bool tensor, got dtype {valid.dtype}")
        if valid.dim() != 4 or valid.shape[0] != x.shape[0] or valid.shape[2:] != x.shape[2:]:
            raise ValueError(
                f"valid must have shape (B, 1 or C, H, W) matching {list(x.shape)}, "
                f"got {list(valid.shape)}"
            )
        if valid.shape[1] != 1 and valid.shape[1] != x.shape[1]:
            raise ValueError(
                f"valid must have 1 or {x.shape[1]} channels, got shape {list(valid.shape)}"
            )


def wavelet_sigma(
    x: torch.Tensor, valid: torch.Tensor | None, kernel: torch.Tensor
) -> torch.Tensor:
    """:func:`estimate_sigma` without argument checks; ``x`` float32/64, ``kernel`` from
    :func:`hh_kernel` in the dtype of ``x``, ``valid`` (B, C, H, W) bool or None."""
    if x.shape[-2] < 4 or x.shape[-1] < 4:  # no 4 x 4 block: nothing to estimate from
        return torch.zeros(x.shape[0], x.shape[1], dtype=x.dtype, device=x.device)
    d = _detail(x, kernel)
    keep = _valid_coefficients(x, valid, kernel) & (d != 0)
    return _median_abs(d, keep) * K.MAD_TO_SIGMA


def wavelet_noise_k(
    x: torch.Tensor, amplitude: torch.Tensor, valid: torch.Tensor | None, kernel: torch.Tensor
) -> torch.Tensor:
    """:func:`estimate_noise_k` without argument checks (same conventions as above)."""
    B, C, H, W = x.shape
    if H < 4 or W < 4:  # no 4 x 4 block: nothing to estimate from
        return torch.zeros(B, C, dtype=x.dtype, device=x.device)
    amp_ok = torch.isfinite(amplitude) & (amplitude > 0)
    ok = amp_ok.expand(B, C, H, W)
    if valid is not None:
        ok = ok & valid
    d = _detail(x, kernel)
    safe = torch.where(amp_ok, amplitude, torch.ones_like(amplitude))
    inv_a2 = torch.where(amp_ok, 1.0 / (safe * safe), torch.zeros_like(amplitude))
    s2 = F.conv2d(inv_a2, kernel * kernel, stride=2)  # (B, 1, h, w): var(d) / k^2
    keep = _valid_coefficients(x, ok, kernel) & (d != 0) & (s2 > 0)
    ratio = d / s2.clamp_min(1e-30).sqrt()
    return _median_abs(ratio, keep) * K.MAD_TO_SIGMA


def estimate_sigma(x: torch.Tensor, valid: torch.Tensor | None = None) -> torch.Tensor:
    r"""Robust Gaussian noise standard deviation per image and channel (wavelet MAD).

    Args:
        x: (B, C, H, W) floating image. NaN/inf pixels are ignored.
        valid: optional (B, 1 or C, H, W) bool mask of usable pixels (e.g. ``depth != 0``).

    Returns:
        (B, C) estimates in the units of ``x``; 0 where no valid 4 x 4 block has a non-zero
        detail coefficient.

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> noisy = 0.1 * torch.randn(1, 1, 256, 256, generator=g)
        >>> round(float(estimate_sigma(noisy)), 2)
        0.1
    """
    check_image(x, "x")
    _check_valid(valid, x)
    work = x if x.dtype == torch.float64 else x.float()
    if valid is not None:
        valid = valid.expand(x.shape[0], x.shape[1], x.shape[2], x.shape[3])
    return wavelet_sigma(work, valid, hh_kernel(work.dtype, work.device)).to(x.dtype)


def estimate_noise_k(
    x: torch.Tensor, amplitude: torch.Tensor, valid: torch.Tensor | None = None
) -> torch.Tensor:
    r"""Estimate ``k`` of the ToF noise law ``sigma_D = k / A`` (eq. 2) per image and channel.

    Args:
        x: (B, C, H, W) depth.
        amplitude: (B, 1, H, W) amplitude; pixels with ``A <= 0`` or non-finite are ignored.
        valid: optional (B, 1 or C, H, W) bool mask of usable pixels.

    Returns:
        (B, C) estimates of ``k`` (depth units times amplitude units).
    """
    check_image(x, "x")
    check_image(amplitude, "amplitude", 1)
    if amplitude.shape[0] != x.shape[0] or amplitude.shape[2:] != x.shape[2:]:
        raise ValueError(
            f"amplitude must have shape (B, 1, H, W) = {[x.shape[0], 1, x.shape[2], x.shape[3]]}, "
            f"got {list(amplitude.shape)}"
        )
    _check_valid(valid, x)
    work = x if x.dtype == torch.float64 else x.float()
    if valid is not None:
        valid = valid.expand(x.shape[0], x.shape[1], x.shape[2], x.shape[3])
    kernel = hh_kernel(work.dtype, work.device)
    return wavelet_noise_k(work, amplitude.to(work.dtype), valid, kernel).to(x.dtype)


def mad_to_sigma(median_abs: torch.Tensor, channels: int) -> torch.Tensor:
    """The standard deviation of each of the ``channels`` (1 or 2) i.i.d. Gaussian components of
    ``e`` from the median of ``|e|``: ``MAD_TO_SIGMA`` times it for one channel (the MAD), divided
    by ``sqrt(2 ln 2)`` (the median of a Rayleigh variable) for two."""
    if channels == 1:
        return median_abs * K.MAD_TO_SIGMA
    return median_abs / math.sqrt(2.0 * math.log(2.0))


def clipped_scale(
    e: torch.Tensor, keep: torch.Tensor | None = None, dims: list[int] | None = None
) -> torch.Tensor:
    """Robust standard deviation of ``e`` over ``keep`` (None: all), reduced over ``dims`` (None:
    all dims) and kept as size-1 dims: the clipped mean ``|e|`` of the module docstring.

    Starts from ``sqrt(pi / 2) mean |e|`` (the mean ``|e|`` of a normal is ``sigma sqrt(2 / pi)``)
    and takes three times the mean of the ``|e| <= 3 s`` divided by ``0.786619`` (the de-biasing
    factor of the clipping; for a normal the conditional mean ``E[|e| : |e| <= 3 sigma]`` is
    ``0.791157 sigma``, so the estimate is 0.6 % high: kept as it has always been). 0 where
    nothing is kept. Sums only (no sort, no data-dependent shapes): it traces and exports.

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> e = torch.randn(1, 1, 200, 200, generator=g)
        >>> round(float(clipped_scale(e)), 2)  # sigma 1, the 0.6 % bias, the draw
        1.01
    """
    axes = list(range(e.dim())) if dims is None else dims
    ok = torch.ones_like(e, dtype=torch.bool) if keep is None else keep
    a = torch.where(ok, e.abs(), torch.zeros_like(e))
    n = ok.sum(axes, keepdim=True).clamp_min(1).to(e.dtype)
    s = 1.2533141373155003 * a.sum(axes, keepdim=True) / n  # sqrt(pi / 2) mean |e|
    for _ in range(3):
        inside = ok & (a <= 3.0 * s)
        m = inside.sum(axes, keepdim=True).clamp_min(1).to(e.dtype)
        s = torch.where(inside, a, torch.zeros_like(a)).sum(axes, keepdim=True) / (0.786619 * m)
    return s


def scale_moment(channels: int, clip: float) -> float:
    """``E[|e|^2 | |e| <= clip sigma] / sigma^2`` for ``e`` with ``channels`` i.i.d. N(0, sigma^2)
    components (1: truncated normal; 2: truncated Rayleigh), used to de-bias the clipped RMS."""
    c = float(clip)
    if channels == 1:
        p = math.erf(c / math.sqrt(2.0))
        dens = math.exp(-0.5 * c * c) / math.sqrt(2.0 * math.pi)
        return 1.0 - 2.0 * c * dens / p
    t = 0.5 * c * c
    p = 1.0 - math.exp(-t)
    return 2.0 * (1.0 - math.exp(-t) * (1.0 + t)) / p


def clipped_rms_scale(
    mag: torch.Tensor, ok: torch.Tensor | None, clip: float, moment: float, channels: int
) -> torch.Tensor:
    """Per-image scale (N,) of the per-channel noise from magnitudes ``mag`` (N, 1, R, C) at the
    usable entries ``ok`` (None: all): the median start of :func:`mad_to_sigma` (the RMS where
    that is 0) refined by two clipped-RMS iterations (``|e| <= clip sigma``) de-biased by
    ``moment`` (:func:`scale_moment` of ``channels`` and ``clip``)."""
    n = mag.shape[0]
    flat = mag.reshape(n, -1)
    sq = flat * flat
    if ok is None:
        okf = torch.ones_like(flat, dtype=torch.bool)
        med = flat.median(dim=1).values
    else:
        okf = ok.reshape(n, -1)
        sq = torch.where(okf, sq, 0.0)
        med = torch.nanmedian(torch.where(okf, flat, math.nan), dim=1).values
        med = torch.nan_to_num(med, nan=0.0)
    count = okf.sum(1).to(mag.dtype)
    start = mad_to_sigma(med, channels)
    rms = torch.sqrt(sq.sum(1) / count.clamp_min(1.0) / channels)
    sigma = torch.where(start > 0, start, rms)
    for _ in range(2):
        sel = okf & (flat <= clip * sigma[:, None])
        m2 = torch.where(sel, sq, 0.0).sum(1) / sel.sum(1).clamp_min(1)
        sigma = torch.sqrt(m2 / moment)
    return sigma


#: log 3 - digamma(3): minus the mean of log(chi2_6 / 6), the de-biasing of the fitted log level
_LOG_CHI2_6_BIAS = 0.17582795
#: residuals (natural-log units) kept by the fit of :func:`facet_noise`
_FACET_NOISE_CLIP = 2.0


def facet_noise(
    depth: torch.Tensor,
    amplitude: torch.Tensor | None = None,
    min_noise: float = 1e-3,
    clip: float = _FACET_NOISE_CLIP,
    bias: float = _LOG_CHI2_6_BIAS,
    residuals: torch.Tensor | None = None,
) -> torch.Tensor:
    """Per-pixel depth noise (standard deviation) from the law ``sigma^2 = e^c A^-gamma`` fitted
    per frame to local 3 x 3 plane-fit residuals (module docstring).

    Args:
        depth: (B, 1, H, W) depth; NaN (or any invalid value made NaN by the caller) is ignored.
        amplitude: (B, 1, H, W) amplitude, or None (one level per frame).
        min_noise: the floor of the map, in depth units (quantised depth can have a 0 residual).
        clip, bias: the fit's trimming (log units) and de-biasing (the module's defaults).
        residuals: the (B, 1, H, W) residual variances of the 3 x 3 plane fits of ``depth`` when
            the caller has them (NaN where a window is not valid); computed when None.

    Returns:
        (B, 1, H, W) noise in depth units, ``>= min_noise``; pixels with ``A <= 0`` get the value
        of the smallest positive amplitude the law allows (``A`` clamped at 1e-6).

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> d = 2.0 + 0.01 * torch.randn(1, 1, 64, 64, generator=g)
        >>> round(float(facet_noise(d).median()), 3)
        0.01
    """
    v = plane_fit(depth, 3, 3)[3] if residuals is None else residuals
    ok = (v > 0) & (v < math.inf)  # finite and > 0 (NaN fails both)
    lv = torch.log(torch.where(ok, v, torch.ones_like(v)))
    if amplitude is None:
        la = torch.zeros_like(v)
    else:
        a_ok = (amplitude > 0) & (amplitude < math.inf)
        ok = ok & a_ok
        la = torch.log(torch.where(a_ok, amplitude, torch.ones_like(amplitude)))
    w = ok.to(v.dtype)
    c0 = torch.zeros(v.shape[0], 1, 1, 1, dtype=v.dtype, device=v.device)
    gamma = torch.zeros_like(c0)
    dims = [1, 2, 3]
    for it in range(3):
        n = w.sum(dims, keepdim=True)
        nz = n.clamp_min(1.0)
        mx = (w * la).sum(dims, keepdim=True) / nz
        my = (w * lv).sum(dims, keepdim=True) / nz
        if amplitude is not None:
            dla = la - mx
            wdla = w * dla
            cov = (wdla * (lv - my)).sum(dims, keepdim=True)
            var = (wdla * dla).sum(dims, keepdim=True)
            gamma = torch.clamp(-cov / var.clamp_min(1e-12), 0.0, 2.0)
        c0 = torch.where(n > 0, my + gamma * mx, torch.full_like(c0, -1e30))
        if it < 2:  # the weights of the next round: |lv - (c0 - gamma la)| < clip
            keep = (gamma * la).neg_().add_(c0).neg_().add_(lv).abs_() < clip
            w = (ok & keep).to(v.dtype)
    if amplitude is None:
        la_px = torch.zeros_like(depth)
    else:
        la_px = torch.log(torch.clamp(torch.nan_to_num(amplitude, nan=1.0), min=1e-6))
    # exp(0.5 (c0 - gamma la + bias)), worked on in place
    sigma = (gamma * la_px).neg_().add_(c0).add_(bias).mul_(0.5).exp_()
    return sigma.clamp_(min=min_noise)
