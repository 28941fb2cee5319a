"""Depth-quality metrics of Georgiev et al. (SAS 2015): PSNR (eq. 9), RMSE, MAE, LOW / IMP shares.

Eq. (9) (garbled in the seed text) reads, with ``N_P`` the number of evaluated pixels::

    MSE = (1 / N_P) sum_x (D_GT(x) - D_C(x))^2,      PSNR = 20 log10(D_MAX / sqrt(MSE))  [dB]

i.e. the usual ``10 log10(D_MAX^2 / MSE)`` with the peak set to the depth range
:data:`~tof_fpn_torch.constants.D_MAX` (7.5 m, the 20 MHz unambiguous range ``c_L / 2f = 7.49 m``),
whatever the scene's actual maximum.

Masks: every function takes an optional ``mask`` (B, 1, H, W) bool. The evaluated pixels are
``mask & valid_mask(target)`` (:func:`~tof_fpn_torch.runtime.valid_mask`, the package's one
validity rule): a ground-truth pixel that is NaN, inf or <= 0 never counts. A non-finite
*prediction* inside the evaluated pixels raises :class:`ValueError` rather than being dropped
silently; exclude such pixels with ``mask`` (e.g. ``valid_mask(pred)``) if that is what you want,
and report how many you dropped. A zero prediction is a number and counts as an error of ``D_GT``.

All functions are batched and return one value per image, shape (B,); TorchScript-compatible.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from .. import constants as K
from ..runtime.validity import valid_mask

__all__ = [
    "impulsive_fraction",
    "impulsive_mask",
    "low_sensing_fraction",
    "mae",
    "mse",
    "psnr",
    "rmse",
    "sensing_stats",
]


def _check_map(x: torch.Tensor, name: str) -> None:
    if x.dim() != 4 or x.shape[1] != 1:
        raise ValueError(f"{name} must have shape (B, 1, H, W), got {list(x.shape)}")
    if not x.is_floating_point():
        raise ValueError(f"{name} must be floating point, got dtype {x.dtype}")


def _eval_mask(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
    _check_map(pred, "pred")
    _check_map(target, "target")
    if pred.shape != target.shape:
        raise ValueError(
            f"pred and target must have the same shape, got {list(pred.shape)} and {list(target.shape)}"
        )
    m = valid_mask(target)
    if mask is not None:
        if mask.shape != target.shape or mask.dtype != torch.bool:
            raise ValueError(
                f"mask must be a bool tensor of shape {list(target.shape)}, got dtype "
                f"{mask.dtype} and shape {list(mask.shape)}"
            )
        m = m & mask
    counts = m.flatten(1).sum(dim=1)
    if bool((counts == 0).any()):
        empty: list[int] = torch.nonzero(counts == 0).flatten().tolist()
        raise ValueError(f"no valid pixel to evaluate in image(s) {empty} (mask & valid target)")
    bad = m & ~torch.isfinite(pred)
    if bool(bad.any()):
        raise ValueError(
            f"pred has {int(bad.sum())} NaN/inf value(s) at evaluated pixels; exclude them with "
            "mask=valid_mask(pred) (and report the share) or fill them"
        )
    return m


def _masked_mean(err: torch.Tensor, m: torch.Tensor) -> torch.Tensor:
    err = torch.where(m, err, torch.zeros_like(err))
    return err.flatten(1).sum(dim=1) / m.flatten(1).sum(dim=1).to(err.dtype)


def mse(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """Mean squared depth error per image, (B,), over ``mask & valid_mask(target)``."""
    m = _eval_mask(pred, target, mask)
    d = pred - target
    return _masked_mean(d * d, m)


def rmse(
    pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None
) -> torch.Tensor:
    """Root mean squared depth error per image (metres), (B,)."""
    return torch.sqrt(mse(pred, target, mask))


def mae(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """Mean absolute depth error per image (metres), (B,)."""
    m = _eval_mask(pred, target, mask)
    return _masked_mean(torch.abs(pred - target), m)


def psnr(
    pred: torch.Tensor,
    target: torch.Tensor,
    mask: torch.Tensor | None = None,
    d_max: float = K.D_MAX,
) -> torch.Tensor:
    """Eq. (9): ``20 log10(d_max / sqrt(MSE))`` per image, dB, (B,); ``inf`` for a perfect match.

    Args:
        pred, target: (B, 1, H, W) depth in metres (target: the ground truth ``D_GT``).
        mask: optional (B, 1, H, W) bool, pixels to evaluate (ANDed with the valid target).
        d_max: the peak, :data:`~tof_fpn_torch.constants.D_MAX` in the paper (> 0).
    """
    if not d_max > 0.0:
        raise ValueError(f"d_max must be > 0 m, got {d_max}")
    err = mse(pred, target, mask)
    return 10.0 * torch.log10((d_max * d_max) / err)


def low_sensing_fraction(
    amplitude: torch.Tensor,
    threshold: float = K.LOW_SENSING_THRESHOLD,
    mask: torch.Tensor | None = None,
) -> torch.Tensor:
    """Share (0..1) of pixels with ``A < threshold`` per image, (B,) (Table II's LOW / 100).

    Non-finite amplitudes count as low-sensing (they carry no measurement). ``mask`` restricts the
    pixels counted.
    """
    _check_map(amplitude, "amplitude")
    low = ~(amplitude >= threshold)  # NaN -> low
    m = torch.ones_like(low) if mask is None else mask
    if m.shape != low.shape or m.dtype != torch.bool:
        raise ValueError(f"mask must be a bool tensor of shape {list(low.shape)}")
    return _masked_mean(low.to(amplitude.dtype), m)


def _median3x3(depth: torch.Tensor) -> torch.Tensor:
    """3 x 3 median ignoring invalid pixels (NaN inside), replicate padding, (B, 1, H, W).

    Hand-written on purpose: ``kornia.filters.median_blur`` returns NaN for any window that holds
    an invalid pixel, and the point here is the median of the *valid* neighbours."""
    b, _, h, w = depth.shape
    x = torch.where(valid_mask(depth), depth, torch.full_like(depth, float("nan")))
    x = F.pad(x, (1, 1, 1, 1), mode="replicate")
    patches = F.unfold(x, kernel_size=3).view(b, 9, h, w)
    return torch.nanmedian(patches, dim=1, keepdim=True).values


def impulsive_mask(
    depth: torch.Tensor, reference: torch.Tensor | None = None, threshold: float = 0.5
) -> torch.Tensor:
    """Impulsive / no-information pixels (the paper's IMP), (B, 1, H, W) bool.

    A pixel is impulsive if its depth is invalid (NaN, inf or <= 0) or if it departs by more than
    ``threshold`` metres from ``reference`` -- the ground truth when given, otherwise the 3 x 3
    median of the valid neighbours (an isolated spike). The paper gives no numeric rule for IMP;
    this is ours, stated in docs/simulator.md.
    """
    _check_map(depth, "depth")
    if not threshold > 0.0:
        raise ValueError(f"threshold must be > 0 m, got {threshold}")
    ref = _median3x3(depth) if reference is None else reference
    if ref.shape != depth.shape:
        raise ValueError(f"reference must have shape {list(depth.shape)}, got {list(ref.shape)}")
    invalid = ~valid_mask(depth)
    far = torch.abs(depth - ref) > threshold  # NaN reference -> False
    return invalid | far


def impulsive_fraction(
    depth: torch.Tensor,
    reference: torch.Tensor | None = None,
    threshold: float = 0.5,
    mask: torch.Tensor | None = None,
) -> torch.Tensor:
    """Share (0..1) of :func:`impulsive_mask` pixels per image, (B,) (Table II's IMP / 100)."""
    imp = impulsive_mask(depth, reference, threshold)
    m = torch.ones_like(imp) if mask is None else mask
    if m.shape != imp.shape or m.dtype != torch.bool:
        raise ValueError(f"mask must be a bool tensor of shape {list(imp.shape)}")
    return _masked_mean(imp.to(depth.dtype), m)


def sensing_stats(
    depth: torch.Tensor,
    amplitude: torch.Tensor,
    reference: torch.Tensor | None = None,
    low_threshold: float = K.LOW_SENSING_THRESHOLD,
    impulse_threshold: float = 0.5,
) -> dict[str, torch.Tensor]:
    """Table II's ``{LOW, IMP}`` in percent per image: ``{"low": (B,), "imp": (B,)}``."""
    return {
        "low": 100.0 * low_sensing_fraction(amplitude, low_threshold),
        "imp": 100.0 * impulsive_fraction(depth, reference, impulse_threshold),
    }
