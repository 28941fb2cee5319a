r"""Detect periodic column/row fixed-pattern noise in depth frames (offline analysis, torch).

Georgiev et al. (IEEE SAS 2015, Sec. III) find the CamCube FPN at ``2pi/3`` and ``pi`` and note
that the pattern changes as a sensor wears, so a user's sensor may stripe elsewhere. Column
stripes are constant down a column, so averaging each column over the rows keeps them while the
noise averages out; row stripes likewise with rows and columns swapped.

Method, per orientation:

1. Valid pixels (:func:`~tof_fpn_torch.runtime.valid_mask`) get weight ``w = 1 / (1 + A / low)``: FPN dominates where
   the amplitude is low (Sec. IV-B), so those pixels count most. Without amplitude, ``w = 1``.
2. Each line is high-passed by subtracting its moving average over ``2 * smooth + 1`` valid
   samples (removes the scene's shape; periods shorter than ``~smooth`` pass), and residuals over
   4 robust sigmas of the line (``1.4826 * MAD``) are dropped: those are the samples next to scene
   edges, which would otherwise spread over all frequencies. (A running median instead of the mean
   would keep edges out too, but it is nonlinear and spreads the stripes themselves.)
3. The weighted mean over the other axis gives one profile per frame; its Hann-windowed
   periodogram is averaged over frames.
4. A running median over ``+-max(4, n/16)`` bins estimates the broadband background (scene edges,
   noise, broadband column offsets); a *stripe* is a local maximum above ``min_frequency`` whose
   power exceeds the background by ``threshold_db``.

Each found component reports its frequency (radians/sample, refined by parabolic interpolation of
the log power), strength (amplitude of the periodic profile in depth units), ``snr_db`` (peak over
background) and ``confidence = 1 - background / peak`` in [0, 1].
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import kornia.filters as KF
import torch

from .. import constants as K
from ..runtime._checks import check_image, check_same_shape
from ..runtime.validity import valid_mask

__all__ = ["StripeComponent", "StripeEstimate", "estimate_stripes"]


@dataclass(frozen=True)
class StripeComponent:
    """One periodic stripe pattern.

    Attributes:
        orientation: ``"columns"`` (changes along the width; remove with ``dim=-1``) or ``"rows"``.
        dim: filtering dimension that removes it (-1 or -2).
        frequency: radians per sample in ``(0, pi]``.
        strength: amplitude of the periodic profile (depth units).
        snr_db: peak power over the background, dB.
        confidence: ``1 - background / peak`` in [0, 1].
    """

    orientation: str
    dim: int
    frequency: float
    strength: float
    snr_db: float
    confidence: float


@dataclass(frozen=True)
class StripeEstimate:
    """Result of :func:`estimate_stripes`: components (strongest first) and the spectra used."""

    components: tuple[StripeComponent, ...]
    spectra: dict = field(default_factory=dict, repr=False)

    def notches(self, orientation: str | None = None) -> tuple[float, ...]:
        """Sorted distinct frequencies (optionally of one orientation)."""
        f = {c.frequency for c in self.components if orientation in (None, c.orientation)}
        return tuple(sorted(f))

    @property
    def dims(self) -> tuple[int, ...]:
        """Filtering dimensions needed (sorted)."""
        return tuple(sorted({c.dim for c in self.components}))


def _highpass(x: torch.Tensor, valid: torch.Tensor, half: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Residual of ``x`` from its moving average over ``2 * half + 1`` valid samples along the
    last axis, and a mask that drops outliers (``|r| > 4 * 1.4826 * MAD`` of the line): the
    samples next to scene edges, which would otherwise spread over all frequencies."""
    v = valid.to(x.dtype)
    size = (1, 2 * half + 1)  # kornia's box filter along each line; zero padding outside
    num = KF.box_blur((x * v).unsqueeze(1), size, border_type="constant").squeeze(1)
    den = KF.box_blur(v.unsqueeze(1), size, border_type="constant").squeeze(1)
    r = torch.where(valid, x - num / den.clamp_min(0.5 / (2 * half + 1)), torch.zeros_like(x))
    nan = torch.full_like(r, math.nan)
    mad = torch.nanmedian(torch.where(valid, r.abs(), nan), dim=-1, keepdim=True).values
    keep = valid & (r.abs() <= 4.0 * K.MAD_TO_SIGMA * torch.nan_to_num(mad))
    return r, keep


def _running_median(p: torch.Tensor, half: int) -> torch.Tensor:
    """Running median of a 1-D spectrum over ``2 half + 1`` bins (kornia, reflected ends)."""
    half = min(half, p.numel() - 1)
    return KF.median_blur(p.view(1, 1, 1, -1), (1, 2 * half + 1), "reflect").view(-1)


def _analyse(
    depth: torch.Tensor,
    weight: torch.Tensor,
    orientation: str,
    dim: int,
    smooth: int,
    min_frequency: float,
    threshold_db: float,
    max_components: int,
) -> tuple[list[StripeComponent], dict]:
    # depth, weight: (B, H, W) with the profile axis last
    n = depth.shape[-1]
    high, keep = _highpass(depth, weight > 0, smooth)
    weight = torch.where(keep, weight, torch.zeros_like(weight))
    wsum = weight.sum(-2)
    profile = (weight * high).sum(-2) / wsum.clamp_min(1e-12)  # (B, n)
    frames_ok = (wsum > 0).to(depth.dtype)
    profile = (
        profile
        - (profile * frames_ok).sum(-1, keepdim=True)
        / frames_ok.sum(-1, keepdim=True).clamp_min(1.0)
    ) * frames_ok
    window = torch.hann_window(n, periodic=False, dtype=depth.dtype, device=depth.device)
    spec = torch.fft.rfft(profile * window, dim=-1)
    power = (spec.real**2 + spec.imag**2).mean(0)  # (n//2 + 1,)
    freqs = torch.arange(power.numel(), dtype=depth.dtype, device=depth.device) * (2 * math.pi / n)
    background = _running_median(power, max(4, n // 16)).clamp_min(torch.finfo(depth.dtype).tiny)
    ratio = power / background
    thr = 10.0 ** (threshold_db / 10.0)
    found: list[StripeComponent] = []
    p = power.tolist()
    r = ratio.tolist()
    bg = background.tolist()
    last = len(p) - 1
    wsum_win = float(window.sum())
    candidates = []
    for k in range(1, last + 1):
        if 2 * math.pi * k / n < min_frequency or r[k] < thr:
            continue
        if p[k] < p[k - 1] or (k < last and p[k] < p[k + 1]):
            continue
        candidates.append(k)
    candidates.sort(key=lambda k: -r[k])
    for k in candidates[:max_components]:
        if k < last:  # parabolic interpolation of log power
            a, b, c = (math.log(max(p[j], 1e-300)) for j in (k - 1, k, k + 1))
            den = a - 2 * b + c
            delta = 0.5 * (a - c) / den if den < 0 else 0.0
            freq = min(2 * math.pi * (k + max(-0.5, min(0.5, delta))) / n, math.pi)
            scale = 2.0 / wsum_win
        else:
            freq = math.pi if n % 2 == 0 else 2 * math.pi * k / n
            scale = 1.0 / wsum_win
        found.append(
            StripeComponent(
                orientation=orientation,
                dim=dim,
                frequency=float(freq),
                strength=float(math.sqrt(p[k]) * scale),
                snr_db=float(10.0 * math.log10(r[k])),
                confidence=float(max(0.0, min(1.0, 1.0 - bg[k] / p[k]))),
            )
        )
    spectra = {"frequency": freqs.cpu(), "power": power.cpu(), "background": background.cpu()}
    return found, spectra


def estimate_stripes(
    depth: torch.Tensor,
    amplitude: torch.Tensor | None = None,
    *,
    low: float = K.FUSION_LOW,
    orientations: tuple[str, ...] = ("columns", "rows"),
    smooth: int = 8,
    min_frequency: float = 0.15 * math.pi,
    threshold_db: float = 10.0,
    max_components: int = 4,
) -> StripeEstimate:
    r"""Find periodic column and/or row patterns in depth frames (see the module docstring).

    Args:
        depth: (B, 1, H, W) float depth; invalid pixels (:func:`~tof_fpn_torch.runtime.valid_mask`
            of depth and amplitude) are ignored.
        amplitude: (B, 1, H, W) or None (uniform weights).
        low: amplitude scale of the weights ``1 / (1 + A / low)``.
        orientations: any of ``"columns"`` (periodic along the width), ``"rows"``.
        smooth: half-width of the per-line moving average removed before averaging (>= 1).
        min_frequency: lowest frequency reported, radians/sample in ``(0, pi)``; lower ones are
            scene structure, and a notch there would remove scene content.
        threshold_db: peak-over-background power needed.
        max_components: most components per orientation.

    Returns:
        :class:`StripeEstimate` with components sorted by ``snr_db`` (strongest first).

    Raises:
        ValueError: bad shapes/dtypes, bad parameters, no valid pixel.
    """
    check_image(depth, "depth", 1)
    if amplitude is not None:
        check_image(amplitude, "amplitude", 1)
        check_same_shape(amplitude, depth, "amplitude", "depth")
    bad = [o for o in orientations if o not in ("columns", "rows")]
    if bad or not orientations:
        raise ValueError(f"orientations must be from ('columns', 'rows'), got {orientations!r}")
    if isinstance(smooth, bool) or not isinstance(smooth, int) or smooth < 1:
        raise ValueError(f"smooth must be an int >= 1, got {smooth!r}")
    if not 0.0 < float(min_frequency) < math.pi:
        raise ValueError(f"min_frequency must lie in (0, pi), got {min_frequency!r}")
    if (
        isinstance(max_components, bool)
        or not isinstance(max_components, int)
        or max_components < 1
    ):
        raise ValueError(f"max_components must be an int >= 1, got {max_components!r}")
    if not math.isfinite(low) or low <= 0:
        raise ValueError(f"low must be finite and > 0, got {low!r}")
    d = depth[:, 0].double()
    valid = valid_mask(depth, amplitude)[:, 0]
    if amplitude is not None:
        a = amplitude[:, 0].double()
        w = 1.0 / (1.0 + torch.where(valid, a, torch.zeros_like(a)) / low)
    else:
        w = torch.ones_like(d)
    if not bool(valid.any()):
        raise ValueError("depth has no valid pixel (NaN, inf, <= 0, or invalid amplitude)")
    w = torch.where(valid, w, torch.zeros_like(w))
    d = torch.where(valid, d, torch.zeros_like(d))
    components: list[StripeComponent] = []
    spectra = {}
    for o in orientations:
        if o == "columns":
            dd, ww, dim = d, w, -1
        else:
            dd, ww, dim = d.transpose(-1, -2), w.transpose(-1, -2), -2
        if dd.shape[-1] < 8:
            continue
        found, spec = _analyse(dd, ww, o, dim, smooth, min_frequency, threshold_db, max_components)
        components.extend(found)
        spectra[o] = spec
    components.sort(key=lambda c: -c.snr_db)
    return StripeEstimate(tuple(components), spectra)
