r"""What every denoiser of this package shares (torch only, TorchScript-clean).

* :func:`prepare`: the argument checks, the working dtype, the validity mask of
  :func:`~tof_fpn_torch.runtime.valid_mask` (any channel invalid makes the pixel invalid; the
  amplitude's part of the rule where one is given) and the noise level.
* The noise level, ``sigma`` of every ``forward(depth, amplitude=None, sigma=None)``:

  - a number, a 0-d or (B,) tensor: one standard deviation per image (depth units);
  - a (B, 1, H, W) map: one per pixel (only valid pixels are read);
  - ``None`` without amplitude: estimated per image, wavelet MAD of the valid pixels
    (:func:`~tof_fpn_torch.denoise.estimate_sigma`, the estimator NLM uses);
  - ``None`` with amplitude: the ToF law ``sigma_D = k / A`` (eq. 2 of Georgiev et al. 2015) per
    pixel, ``k`` given or estimated (:func:`~tof_fpn_torch.denoise.estimate_noise_k`); a valid
    pixel with ``A = 0`` counts as ``A`` = :data:`~tof_fpn_torch.constants.NLM_AMPLITUDE_FLOOR`
    times the image's median amplitude, as in NLM.

  A given ``sigma`` must be finite and ``>= 0`` (ValueError otherwise). ``sigma = 0`` (given or
  estimated, e.g. a constant image) means "no noise": that image is returned unchanged.
* :func:`fill_invalid`: invalid pixels replaced by a smooth push-pull interpolation of the valid
  ones, for the block- and window-based denoisers that need a value everywhere; the caller puts
  the invalid pixels back afterwards. A frame without any valid pixel is returned unchanged by
  every denoiser (nothing to denoise).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from .. import constants as K
from ..runtime._checks import check_image
from ..runtime.noise import wavelet_noise_k, wavelet_sigma
from ..runtime.stage import Stage, empty_record
from ..runtime.validity import valid_mask

__all__ = [
    "Denoiser",
    "empty_record",
    "amplitude_floor",
    "as_sigma",
    "check_amplitude",
    "check_k",
    "check_sigma_tensor",
    "check_window",
    "fill_invalid",
    "noise_map",
    "prepare",
    "restore_invalid",
]


def amplitude_floor(amp: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """(B, 1, 1, 1): ``NLM_AMPLITUDE_FLOOR`` times the median of each image's valid amplitudes."""
    pos = torch.where(valid & (amp > 0), amp, torch.full_like(amp, math.nan))
    med = torch.nanmedian(pos.flatten(1), dim=1).values
    return torch.nan_to_num(K.NLM_AMPLITUDE_FLOOR * med, nan=1.0).clamp_min(1e-30).view(-1, 1, 1, 1)


@torch.jit.unused
def as_sigma(sigma):
    """Python numbers (int, NumPy scalars) as float; tensors and None as they are."""
    if sigma is None or isinstance(sigma, (torch.Tensor, float)):
        return sigma
    if isinstance(sigma, (bool, str, bytes)):
        raise ValueError(f"sigma must be a number, a tensor or None, got {type(sigma).__name__}")
    try:
        return float(sigma)
    except (TypeError, ValueError):
        raise ValueError(
            f"sigma must be a number, a tensor or None, got {type(sigma).__name__}"
        ) from None


def check_sigma_tensor(sigma: torch.Tensor, B: int, H: int, W: int) -> None:
    shape = list(sigma.shape)
    ok = sigma.dim() == 0 or (sigma.dim() == 1 and (shape[0] == B or shape[0] == 1))
    if sigma.dim() == 4:
        ok = (
            (shape[0] == B or shape[0] == 1)
            and shape[1] == 1
            and (shape[2] == H or shape[2] == 1)
            and (shape[3] == W or shape[3] == 1)
        )
    if not ok:
        raise ValueError(
            f"sigma must be a float, a 0-d tensor, a (B,) tensor or a (B, 1, H, W) map "
            f"(B={B}, H={H}, W={W}; size-1 axes broadcast), got shape {shape}"
        )
    if not sigma.is_floating_point():
        raise ValueError(f"sigma must be a floating-point tensor, got dtype {sigma.dtype}")


def check_amplitude(amplitude: torch.Tensor, depth: torch.Tensor) -> None:
    check_image(amplitude, "amplitude", 1)
    if amplitude.shape[0] != depth.shape[0] or amplitude.shape[2:] != depth.shape[2:]:
        raise ValueError(
            f"amplitude must have shape (B, 1, H, W) = "
            f"{[depth.shape[0], 1, depth.shape[2], depth.shape[3]]}, got {list(amplitude.shape)}"
        )


def prepare(
    depth: torch.Tensor, amplitude: torch.Tensor | None, signed: bool
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """``(x, valid, amp)``: the depth in the working dtype (float64 stays, the rest float32),
    the (B, 1, H, W) validity mask and the amplitude in the working dtype (or None)."""
    check_image(depth, "depth")
    work = torch.float64 if depth.dtype == torch.float64 else torch.float32
    x = depth.detach().to(work)
    valid = valid_mask(x, signed=signed).all(dim=1, keepdim=True)
    amp: torch.Tensor | None = None
    if amplitude is not None:
        check_amplitude(amplitude, depth)
        a = amplitude.detach().to(device=x.device, dtype=work)
        valid = valid & valid_mask(x[:, :1], a, signed=True)
        amp = a
    return x, valid, amp


def check_k(k: float | None) -> None:
    """``k`` (the noise constant of ``sigma = k / A``) must be None (estimated) or finite > 0."""
    if k is not None and not (k > 0.0 and k < float("inf")):
        raise ValueError("k must be None or a finite number > 0, got " + str(k))


def noise_map(
    x: torch.Tensor,
    valid: torch.Tensor,
    amp: torch.Tensor | None,
    sigma: float | torch.Tensor | None,
    k: float | None,
    wavelet: torch.Tensor,
) -> torch.Tensor:
    """(B, 1, H, W) noise standard deviation (0 at invalid pixels), by the rules above."""
    check_k(k)
    B, C, H, W = x.shape
    wk = wavelet.to(device=x.device, dtype=x.dtype)
    xz = torch.where(valid, x, torch.zeros_like(x))
    vc = valid.expand(B, C, H, W)
    if sigma is None:
        if amp is None:
            s = wavelet_sigma(xz, vc, wk).mean(dim=1).view(B, 1, 1, 1)
            return torch.where(valid, s.expand(B, 1, H, W), torch.zeros_like(valid, dtype=x.dtype))
        if k is None:
            kk = wavelet_noise_k(xz, amp, vc, wk).mean(dim=1)
        else:
            kk = torch.full([B], k, dtype=x.dtype, device=x.device)
        safe = torch.where(valid, amp.clamp_min(amplitude_floor(amp, valid)), torch.ones_like(amp))
        return torch.where(valid, kk.view(B, 1, 1, 1) / safe, torch.zeros_like(safe))
    if isinstance(sigma, float):
        if not (sigma >= 0.0 and sigma < float("inf")):
            raise ValueError(f"sigma must be a finite number >= 0, got {sigma}")
        s = torch.full([B, 1, H, W], sigma, dtype=x.dtype, device=x.device)
        return torch.where(valid, s, torch.zeros_like(s))
    check_sigma_tensor(sigma, B, H, W)
    sg = sigma.detach().to(device=x.device, dtype=x.dtype)
    if sg.dim() == 4:
        sg = sg.expand(B, 1, H, W)
    else:
        sg = sg.reshape(-1).expand(B).reshape(B, 1, 1, 1).expand(B, 1, H, W)
    bad = valid & ~(torch.isfinite(sg) & (sg >= 0))
    if bool(bad.any()):
        raise ValueError(
            f"sigma must be finite and >= 0 at every valid pixel, got {int(bad.sum())} bad value(s)"
        )
    return torch.where(valid, sg, torch.zeros_like(sg))


def fill_invalid(x: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """``x`` (B, C, H, W) with the pixels where ``valid`` (B, 1, H, W) is False replaced by a
    push-pull interpolation of the valid ones (means over 2 x 2 pyramids, coarse to fine); images
    without a valid pixel are set to 0."""
    if bool(valid.all()):
        return x
    m = valid.to(x.dtype)
    xs = torch.where(valid, x, torch.zeros_like(x))
    levels_x: list[torch.Tensor] = [xs]
    levels_m: list[torch.Tensor] = [m]
    while levels_x[-1].shape[-1] > 1 or levels_x[-1].shape[-2] > 1:
        cx = F.avg_pool2d(levels_x[-1], 2, ceil_mode=True) * 4.0
        cm = F.avg_pool2d(levels_m[-1], 2, ceil_mode=True) * 4.0
        levels_x.append(cx)
        levels_m.append(cm)
    est = levels_x[-1] / levels_m[-1].clamp_min(1e-30)
    for i in range(len(levels_x) - 2, -1, -1):
        lx, lm = levels_x[i], levels_m[i]
        up = F.interpolate(est, size=[lx.shape[-2], lx.shape[-1]], mode="nearest")
        est = torch.where(lm > 0, lx / lm.clamp_min(1e-30), up)
    return torch.where(valid, x, est)


def check_window(H: int, W: int, kernel_size: int, name: str) -> None:
    """kornia pads by reflection: the half window must be smaller than the image."""
    if kernel_size // 2 >= H or kernel_size // 2 >= W:
        raise ValueError(
            f"{name}: the image ({H} x {W}) must be larger than half the window "
            f"(kernel_size // 2 = {kernel_size // 2} pixels) in both directions"
        )


def restore_invalid(out: torch.Tensor, depth: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """The result in the dtype of ``depth``, with ``depth``'s values at invalid pixels."""
    return torch.where(valid, out, depth.detach().to(out.dtype)).to(depth.dtype)


class Denoiser(Stage):
    """The base of the denoisers: each class defines ``forward(depth, amplitude=None,
    sigma=None) -> depth`` (``sigma``: module docstring); :meth:`run` is the stage contract's form
    (:mod:`tof_fpn_torch.runtime.stage`): the frame denoised with its own noise estimate, and an
    empty record."""

    def _run(
        self, depth: torch.Tensor, amplitude: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        return self.forward(depth, amplitude, None), empty_record()
