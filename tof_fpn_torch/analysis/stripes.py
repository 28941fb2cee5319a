r"""Detect periodic column / row fixed-pattern noise in depth frames, at any frame size.

Georgiev et al. (IEEE SAS 2015, Sec. III) find the CamCube FPN at ``2pi/3`` and ``pi`` and note that
the pattern changes as a sensor wears, so a user's sensor may stripe elsewhere. Column stripes are
the same in every row, so averaging down the columns keeps them while noise and most scene
structure average out.

Method, per orientation (columns: profiles along the width; rows: along the height):

1. Valid pixels (:func:`~tof_fpn_torch.runtime.valid_mask`) get weight ``1 / (1 + A / median A)``
   (FPN dominates where the amplitude is low, Sec. IV-B; unit-free, so any camera's amplitude
   scale works); without amplitude all weigh 1.
2. Each line is high-passed by its running median: ``r = d - median(d)`` over ``2 smooth + 1``
   samples (kornia's ``median_blur``; holes filled from their valid neighbours first). A median
   keeps step edges, so vertical scene edges leave (almost) no residual; residuals beyond 4 robust
   sigmas (``1.4826 MAD``) are dropped (thin objects, corners).
3. One profile: the weighted mean of ``r`` down every column, over all frames (a fixed pattern is
   the same in every frame), minus its mean.
4. Its Hann-windowed spectrum on a grid 8x finer than the DFT bins (zero padding), so a line between
   bins (any odd width, ``pi`` for odd widths) is found where it is. Every local maximum above
   ``min_frequency`` is a candidate; its frequency is refined by a parabola through the log power.
5. **Line test**: ``T = P(f) / mean P(references)`` with ``R`` (up to 8) reference frequencies 3 to 12
   bins away, inside ``(0, pi)``, away from lines already found. For a smooth local spectrum (noise,
   edges, broadband column offsets) ``T ~ F(2, 2R)``, ``P(T > t) = (1 + t / R)^-R``; with ``M``
   independent frequencies searched the **false-alarm probability** of the component is
   ``min(1, M (1 + T / R)^-R)`` (Bonferroni), reported as ``false_alarm``; ``confidence`` is
   ``1 - false_alarm``. A component is reported when ``false_alarm <= false_alarm_max`` (1 %).
6. **Floor in depth units**: its amplitude ``a`` (from ``P(f) - mean P(references)``) must be at
   least ``min_stripe`` (:data:`~tof_fpn_torch.constants.GATE_MIN_STRIPE`, the run-time gate's
   rule) times the data's own per-pixel noise ``sigma`` (the robust sigma of ``r``, corrected for
   the median filter): a stripe whose power is under 1 % of the noise is not reported.
7. **Snapping**: a frequency within half a DFT bin of a known FPN frequency
   (:data:`~tof_fpn_torch.constants.FPN_FREQUENCIES`: ``2pi/3``, ``pi``) is set to it exactly.
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

_REF_BINS = tuple(range(3, 13))
_MAX_REFS = 8


@dataclass(frozen=True)
class StripeComponent:
    """One periodic stripe pattern.

    Attributes:
        orientation: ``"columns"`` (changes along the width; remove with ``dim=-1``) or ``"rows"``.
        dim: filtering dimension that removes it (-1 or -2).
        frequency: radians per sample in ``(0, pi]``.
        strength: amplitude of the periodic profile (depth units).
        snr_db: ``10 log10 T``, the line's power over its reference frequencies.
        false_alarm: probability that noise alone gives a line this strong somewhere in the
            searched band.
        confidence: ``1 - false_alarm``.
        noise: the per-pixel noise the floor was measured against (depth units).
    """

    orientation: str
    dim: int
    frequency: float
    strength: float
    snr_db: float
    false_alarm: float
    confidence: float
    noise: float


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


def _ring_median(x: torch.Tensor, half: int) -> torch.Tensor:
    """Median of the ``2 half`` neighbours of every sample along the last axis, the sample itself
    left out (reflected ends). Hand-written rather than kornia's ``median_blur``: an odd window
    (kornia's only kind) has a majority of the centre's phase of a period-2 pattern and reproduces a
    stripe at ``pi`` exactly, so ``d - median`` would erase it; an even count of neighbours
    centred on the sample does not (its median of ``+-a`` alternating is 0)."""
    n = x.shape[-1]
    h = min(half, n - 1)
    if h < 1:
        return x
    idx = torch.arange(-h, n + h, device=x.device)
    idx = torch.where(idx < 0, -idx, idx)
    idx = torch.where(idx > n - 1, 2 * (n - 1) - idx, idx)
    win = x.index_select(-1, idx).unfold(-1, 2 * h + 1, 1)  # (..., n, 2h + 1)
    ring = torch.cat([win[..., :h], win[..., h + 1 :]], -1).sort(-1).values
    return 0.5 * (ring[..., h - 1] + ring[..., h])


def _profile(
    d: torch.Tensor, valid: torch.Tensor, w: torch.Tensor, smooth: int
) -> tuple[torch.Tensor, float]:
    """The weighted, outlier-free mean of the high-passed lines (profile axis last), and the
    per-pixel noise sigma."""
    v = valid.to(d.dtype)
    size = (1, 2 * smooth + 1)
    # holes filled from their valid neighbours (kornia box filter, zero padding outside), then a
    # running median along each line: it keeps step edges, so a vertical scene edge leaves no
    # residual to be taken for a column offset
    num = KF.box_blur((d * v).unsqueeze(1), size, border_type="constant").squeeze(1)
    den = KF.box_blur(v.unsqueeze(1), size, border_type="constant").squeeze(1)
    filled = torch.where(valid, d, num / den.clamp_min(1e-12))
    filled = torch.where(den > 0, filled, (d * v).sum() / v.sum().clamp_min(1.0))
    r = torch.where(valid, d - _ring_median(filled, smooth), torch.zeros_like(d))
    mad = float(r[valid].abs().median()) if bool(valid.any()) else 0.0
    sigma = K.MAD_TO_SIGMA * mad
    keep = valid & (r.abs() <= 4.0 * sigma) if sigma > 0 else valid
    wk = torch.where(keep, w, torch.zeros_like(w))
    wsum = wk.sum((0, 1))  # over frames and lines
    p = (wk * r).sum((0, 1)) / wsum.clamp_min(1e-30)
    has = wsum > 0
    if bool(has.any()):
        # columns where the profile is an outlier (the residual of a vertical scene edge or a thin
        # object spanning the frame, broadband) are left out of the spectrum
        dev = (p - p[has].median()).abs()
        has = has & (dev <= 4.0 * K.MAD_TO_SIGMA * dev[has].median().clamp_min(1e-30))
    p = torch.where(has, p - p[has].mean() if bool(has.any()) else p, torch.zeros_like(p))
    # r = d - median(d): white noise keeps about (1 - 1/n) of its variance (the median of n
    # samples varies like a mean of 2 n / pi)
    noise = sigma / math.sqrt(1.0 - math.pi / (2.0 * (2 * smooth + 1)))
    return p, noise


def _analyse(
    p: torch.Tensor,
    noise: float,
    orientation: str,
    dim: int,
    min_frequency: float,
    false_alarm_max: float,
    min_stripe: float,
    max_components: int,
) -> tuple[list[StripeComponent], dict]:
    n = p.numel()
    pad = 8 * (1 << max(0, math.ceil(math.log2(n))))  # >= 8 grid points per DFT bin
    fine = pad / n  # grid points per DFT bin
    window = torch.hann_window(n, periodic=False, dtype=p.dtype, device=p.device)
    spec = torch.fft.rfft(p * window, n=pad)
    power = (spec.real**2 + spec.imag**2).cpu().double()
    wsum = float(window.sum())
    pw = power.tolist()
    last = len(pw) - 1
    df = 2 * math.pi / pad  # grid step
    searched = max(1.0, n * (math.pi - min_frequency) / (2 * math.pi))  # independent frequencies
    cands = [
        j
        for j in range(1, last + 1)
        if j * df >= min_frequency and pw[j] >= pw[j - 1] and (j == last or pw[j] >= pw[j + 1])
    ]
    cands.sort(key=lambda j: -pw[j])
    found: list[StripeComponent] = []
    taken: list[float] = []  # grid indices of the lines found
    for j in cands:
        if len(found) >= max_components:
            break
        if any(abs(j - t) < 2.5 * fine for t in taken):
            continue
        refs = []
        for k in _REF_BINS:
            for sign in (-1, 1):
                i = int(round(j + sign * k * fine))
                if 0 < i < last and all(abs(i - t) >= 2.5 * fine for t in taken):
                    refs.append(i)
        refs = sorted(refs, key=lambda i: abs(i - j))[:_MAX_REFS]
        if len(refs) < 2:
            continue
        ref = sum(pw[i] for i in refs) / len(refs)
        t = pw[j] / max(ref, 1e-300)
        r = len(refs)
        p_fa = min(1.0, searched * (1.0 + t / r) ** (-r))
        if 0 < j < last:  # sub-grid refinement: parabola through the log power
            a, b, c = (math.log(max(pw[i], 1e-300)) for i in (j - 1, j, j + 1))
            den = a - 2 * b + c
            delta = 0.5 * (a - c) / den if den < 0 else 0.0
            freq = min((j + max(-0.5, min(0.5, delta))) * df, math.pi)
        else:
            freq = j * df
        for w0 in K.FPN_FREQUENCIES:  # snap to a known FPN frequency within half a bin
            if abs(freq - w0) < 0.5 * (2 * math.pi / n):
                freq = w0
        scale = 1.0 if abs(freq - math.pi) < 0.5 * (2 * math.pi / n) else 0.5
        amp = math.sqrt(max(pw[j] - ref, 0.0)) / (scale * wsum)
        if p_fa > false_alarm_max or amp < min_stripe * noise:
            continue
        taken.append(j)
        found.append(
            StripeComponent(
                orientation=orientation,
                dim=dim,
                frequency=float(freq),
                strength=float(amp),
                snr_db=float(10.0 * math.log10(max(t, 1e-300))),
                false_alarm=float(p_fa),
                confidence=float(1.0 - p_fa),
                noise=float(noise),
            )
        )
    freqs = torch.arange(len(pw), dtype=torch.float64) * df
    return found, {"frequency": freqs, "power": power, "noise": noise}


def estimate_stripes(
    depth: torch.Tensor,
    amplitude: torch.Tensor | None = None,
    *,
    orientations: tuple[str, ...] = ("columns", "rows"),
    smooth: int = 8,
    min_frequency: float = 0.15 * math.pi,
    false_alarm: float = K.DETECTION_FALSE_ALARM,
    min_stripe: float = K.GATE_MIN_STRIPE,
    max_components: int = 4,
) -> StripeEstimate:
    r"""Find periodic column and/or row patterns in depth frames (see the module docstring).

    Args:
        depth: (B, 1, H, W) float depth; invalid pixels (:func:`~tof_fpn_torch.runtime.valid_mask`
            of depth and amplitude) are ignored. The frames share one fixed pattern.
        amplitude: (B, 1, H, W) or None (uniform weights).
        orientations: any of ``"columns"`` (periodic along the width), ``"rows"``.
        smooth: half-width of the per-line running median removed before averaging (>= 1).
        min_frequency: lowest frequency searched, radians/sample in ``(0, pi)``; lower ones are
            scene structure, and a notch there would remove scene content.
        false_alarm: largest false-alarm probability of a reported component, in ``(0, 1)``.
        min_stripe: smallest reported amplitude in units of the per-pixel noise (>= 0).
        max_components: most components per orientation.

    Returns:
        :class:`StripeEstimate` with components sorted by ``snr_db`` (strongest first).

    Raises:
        ValueError: bad shapes/dtypes, bad parameters, no valid pixel.

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> x = torch.arange(97.0)
        >>> d = 2.0 + 0.01 * torch.randn(2, 1, 60, 97, generator=g) + 0.02 * torch.cos(math.pi * x)
        >>> [(c.orientation, round(c.frequency, 4)) for c in estimate_stripes(d).components]
        [('columns', 3.1416)]
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
    if not 0.0 < float(false_alarm) < 1.0:
        raise ValueError(f"false_alarm must lie in (0, 1), got {false_alarm!r}")
    if not (math.isfinite(float(min_stripe)) and min_stripe >= 0):
        raise ValueError(f"min_stripe must be a finite number >= 0, got {min_stripe!r}")
    if (
        isinstance(max_components, bool)
        or not isinstance(max_components, int)
        or max_components < 1
    ):
        raise ValueError(f"max_components must be an int >= 1, got {max_components!r}")
    valid = valid_mask(depth, amplitude)[:, 0]
    if not bool(valid.any()):
        raise ValueError("depth has no valid pixel (NaN, inf, <= 0, or invalid amplitude)")
    d = torch.where(valid, depth[:, 0].double(), torch.zeros_like(depth[:, 0].double()))
    if amplitude is not None:
        a = torch.where(valid, amplitude[:, 0].double(), torch.zeros_like(d))
        med = float(a[valid].median()) or 1.0
        w = torch.where(valid, 1.0 / (1.0 + a / med), torch.zeros_like(d))
    else:
        w = valid.to(d.dtype)
    components: list[StripeComponent] = []
    spectra = {}
    for o in orientations:
        if o == "columns":
            dd, vv, ww, dim = d, valid, w, -1
        else:
            dd, vv, ww, dim = d.transpose(-1, -2), valid.transpose(-1, -2), w.transpose(-1, -2), -2
        if dd.shape[-1] < 8:
            continue  # fewer than 8 samples per line: no line test possible
        p, noise = _profile(dd, vv, ww, smooth)
        found, spec = _analyse(
            p, noise, o, dim, min_frequency, false_alarm, min_stripe, max_components
        )
        components.extend(found)
        spectra[o] = spec
    components.sort(key=lambda c: -c.snr_db)
    return StripeEstimate(tuple(components), spectra)
