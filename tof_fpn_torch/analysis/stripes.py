r"""Detect periodic column / row fixed-pattern noise in depth frames, at any frame size.

Georgiev et al. (IEEE SAS 2015, Sec. III) find the CamCube FPN at ``2pi/3`` and ``pi`` and note that
the pattern changes as a sensor wears, so a user's sensor may stripe elsewhere. Column stripes are
the same in every row, so averaging down the columns keeps them while noise and most scene
structure average out.

Method, per orientation (columns: profiles along the width; rows: along the height):

1. Valid pixels (:func:`~tof_fpn_torch.runtime.valid_mask`) get weight ``1 / (1 + A / median A)``
   (FPN dominates where the amplitude is low, Sec. IV-B; unit-free, so any camera's amplitude
   scale works); without amplitude all weigh 1.
2. Each line is high-passed: ``r = d - box(d)`` (kornia's box filter over ``2 smooth + 1`` valid
   samples; a linear filter, so the stripe's gain ``1 - B(w)`` is known and divided out of its
   strength). Pixels within the box's reach of a scene edge (a central difference beyond 4 robust
   sigmas) and residuals beyond 4 robust sigmas (``1.4826 MAD``) are dropped. (A running median
   keeps steps without that, but its gain on a stripe depends on the local slope of the scene, up
   to 1.5x at ``2pi/3``: it biases the strength.)
3. One profile: the weighted mean of ``r`` down every column, over all frames (a fixed pattern is
   the same in every frame), minus its mean; columns where the profile is an outlier (what is left
   of a vertical edge spanning the frame, a thin object) are left out.
4. Its Hann-windowed spectrum on a grid 8x finer than the DFT bins (zero padding), so a line between
   bins (any odd width, ``pi`` for odd widths) is found where it is. Every local maximum above
   ``min_frequency`` is a candidate; its frequency is refined by a parabola through the log power.
5. **Line test**: ``T = P(f) / mean P(references)`` with ``R`` (up to 8) reference frequencies 3 to 12
   bins away, inside ``(0, pi)``, away from lines already found. For a smooth local spectrum (noise,
   edges, broadband column offsets) ``T ~ F(2, 2R)``, ``P(T > t) = (1 + t / R)^-R``; with ``M``
   frequencies searched (twice the DFT bins in the band: the maximum over a continuous frequency
   beats the bins') the **false-alarm probability** of the component is
   ``min(1, M (1 + T / R)^-R)`` (Bonferroni), reported as ``false_alarm``; ``confidence`` is
   ``1 - false_alarm``. A component is reported when ``false_alarm`` is within the budget
   (:data:`~tof_fpn_torch.constants.DETECTION_FALSE_ALARM`, 1 % for the whole estimate, split
   over the orientations).
6. **Floor in depth units**: its amplitude ``a`` (from ``P(f) - mean P(references)``) must be at
   least ``min_stripe`` (:data:`~tof_fpn_torch.constants.GATE_MIN_STRIPE`, the run-time gate's
   rule) times the data's own per-pixel noise ``sigma`` (the robust sigma of ``r``, corrected for
   the box filter): a stripe whose power is under 1 % of the noise is not reported.
7. **Snapping**: a frequency within half a DFT bin of a known FPN frequency
   (:data:`~tof_fpn_torch.constants.FPN_FREQUENCIES`: ``2pi/3``, ``pi``) is set to it exactly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

from .. import constants as K
from ..runtime._checks import check_image, check_same_shape
from ..runtime.validity import valid_mask
from ._stripe_profile import _profile, _weights

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


def _box_gain(w: float, length: int) -> float:
    """``|1 - B(w)|``: the gain of ``d - box(d)`` (box of ``length`` samples) at ``w``."""
    s = math.sin(w / 2.0)
    b = 1.0 if abs(s) < 1e-12 else math.sin(length * w / 2.0) / (length * s)
    return abs(1.0 - b)


@dataclass
class _Lines:
    """The line test of :func:`_analyse` on one spectrum (module docstring, steps 4-7): the power
    ``pw`` on the fine grid, the lines found so far (``taken``, grid indices) and what a component
    records."""

    pw: list[float]
    n: int
    fine: float
    df: float
    wsum: float
    searched: float
    noise: float
    box: int
    orientation: str
    dim: int
    false_alarm_max: float
    min_stripe: float
    taken: list[float] = field(default_factory=list)

    @property
    def last(self) -> int:
        return len(self.pw) - 1

    def usable(self, i: int) -> bool:
        return 0 < i < self.last and all(abs(i - t) >= 2.5 * self.fine for t in self.taken)

    def references(self, j: int) -> list[int]:
        """Reference indices of candidate ``j``, away from the lines found: in pairs on both
        sides, so a sloping background does not bias T; one-sided only next to pi, where nothing
        lies beyond."""
        refs = []
        for k in _REF_BINS:
            lo, hi = int(round(j - k * self.fine)), int(round(j + k * self.fine))
            if self.usable(lo) and self.usable(hi):
                refs += [lo, hi]
            elif self.usable(lo) and j * self.df > math.pi - 3 * (2 * math.pi / self.n):
                refs.append(lo)
        return refs[:_MAX_REFS]

    def frequency(self, j: int) -> float:
        """The frequency of the line at grid index ``j``: sub-grid refined by a parabola through
        the log power, snapped to a known FPN frequency within half a DFT bin."""
        pw, df = self.pw, self.df
        if 0 < j < self.last:
            a, b, c = (math.log(max(pw[i], 1e-300)) for i in (j - 1, j, j + 1))
            den = a - 2 * b + c
            delta = 0.5 * (a - c) / den if den < 0 else 0.0
            freq = min((j + max(-0.5, min(0.5, delta))) * df, math.pi)
        else:
            freq = j * df
        for w0 in K.FPN_FREQUENCIES:  # snap to a known FPN frequency within half a bin
            if abs(freq - w0) < 0.5 * (2 * math.pi / self.n):
                freq = w0
        return freq

    def line(self, j: int) -> StripeComponent | None:
        """The line test of candidate ``j`` against references away from the lines found."""
        refs = self.references(j)
        if len(refs) < 2:
            return None
        pw = self.pw
        ref = sum(pw[i] for i in refs) / len(refs)
        t = pw[j] / max(ref, 1e-300)
        r = len(refs)
        p_fa = min(1.0, self.searched * (1.0 + t / r) ** (-r))
        freq = self.frequency(j)
        scale = 1.0 if abs(freq - math.pi) < 0.5 * (2 * math.pi / self.n) else 0.5
        gain = max(_box_gain(freq, self.box), 1e-3)
        amp = math.sqrt(max(pw[j] - ref, 0.0)) / (scale * self.wsum * gain)
        if p_fa > self.false_alarm_max or amp < self.min_stripe * self.noise:
            return None
        return StripeComponent(
            orientation=self.orientation,
            dim=self.dim,
            frequency=float(freq),
            strength=float(amp),
            snr_db=float(10.0 * math.log10(max(t, 1e-300))),
            false_alarm=float(p_fa),
            confidence=float(1.0 - p_fa),
            noise=float(self.noise),
        )


def _analyse(
    p: torch.Tensor,
    has: torch.Tensor,
    noise: float,
    box: int,
    orientation: str,
    dim: int,
    min_frequency: float,
    false_alarm_max: float,
    min_stripe: float,
    max_components: int,
) -> tuple[list[StripeComponent], dict]:
    n = p.numel()
    pad = 8 * (1 << max(0, math.ceil(math.log2(n))))  # >= 8 grid points per DFT bin
    window = torch.hann_window(n, periodic=False, dtype=p.dtype, device=p.device)
    spec = torch.fft.rfft(p * window, n=pad)
    power = (spec.real**2 + spec.imag**2).cpu().double()
    lines = _Lines(
        pw=power.tolist(),
        n=n,
        fine=pad / n,  # grid points per DFT bin
        df=2 * math.pi / pad,  # grid step
        wsum=float((window * has).sum()),  # the window over the columns present (gaps left out)
        # frequencies searched: the DFT bins in the band, twice (the maximum over a continuous
        # frequency, found on the 8x finer grid, beats the bins' maximum)
        searched=max(1.0, 2.0 * n * (math.pi - min_frequency) / (2 * math.pi)),
        noise=noise,
        box=box,
        orientation=orientation,
        dim=dim,
        false_alarm_max=false_alarm_max,
        min_stripe=min_stripe,
    )
    pw, last, df = lines.pw, lines.last, lines.df
    cands = [
        j
        for j in range(1, last + 1)
        if j * df >= min_frequency and pw[j] >= pw[j - 1] and (j == last or pw[j] >= pw[j + 1])
    ]
    cands.sort(key=lambda j: -pw[j])
    found: list[StripeComponent] = []
    # strongest candidate first; after each line found, the candidates not yet taken are tested
    # again from the strongest: their references no longer include it (on a short profile the
    # references of the line at pi reach down to a line at 2 pi / 3 and hid it)
    while len(found) < max_components:
        for j in cands:
            free = all(abs(j - t) >= 2.5 * lines.fine for t in lines.taken)
            if lines.usable(j) or (j == last and free):
                comp = lines.line(j)
                if comp is not None:
                    lines.taken.append(j)
                    found.append(comp)
                    break
        else:
            break
    freqs = torch.arange(len(pw), dtype=torch.float64) * df
    return found, {"frequency": freqs, "power": power, "noise": noise}


def _check_arguments(
    depth, amplitude, orientations, smooth, min_frequency, false_alarm, min_stripe, max_components
) -> None:
    """The checks of :func:`estimate_stripes` (ValueError naming the argument)."""
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


def _orientation(
    d: torch.Tensor,
    valid: torch.Tensor,
    w: torch.Tensor,
    orientation: str,
    smooth: int,
    min_frequency: float,
    false_alarm_max: float,
    min_stripe: float,
    max_components: int,
) -> tuple[list[StripeComponent], dict] | None:
    """The components and the spectrum of one orientation (None: lines too short to test)."""
    if orientation == "columns":
        dd, vv, ww, dim = d, valid, w, -1
    else:
        dd, vv, ww, dim = d.transpose(-1, -2), valid.transpose(-1, -2), w.transpose(-1, -2), -2
    if dd.shape[-1] < 8:
        return None  # fewer than 8 samples per line: no line test possible
    half = min(smooth, max(1, dd.shape[-1] // 4))  # short lines: a shorter box
    p, has, noise = _profile(dd, vv, ww, half)
    if int(has.sum()) < 8:
        return None  # fewer than 8 usable samples per line: no line test possible
    box = 2 * half + 1
    return _analyse(
        p,
        has,
        noise,
        box,
        orientation,
        dim,
        min_frequency,
        false_alarm_max,
        min_stripe,
        max_components,
    )


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
        smooth: half-width of the per-line box filter removed before averaging (>= 1).
        min_frequency: lowest frequency searched, radians/sample in ``(0, pi)``; lower ones are
            scene structure, and a notch there would remove scene content.
        false_alarm: false-alarm budget of the whole estimate, in ``(0, 1)``: each orientation
            reports components whose false-alarm probability is within its share.
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
    args = (orientations, smooth, min_frequency, false_alarm, min_stripe, max_components)
    _check_arguments(depth, amplitude, *args)
    valid = valid_mask(depth, amplitude)[:, 0]
    if not bool(valid.any()):
        raise ValueError("depth has no valid pixel (NaN, inf, <= 0, or invalid amplitude)")
    d, w = _weights(depth, amplitude, valid)
    components: list[StripeComponent] = []
    spectra = {}
    budget = false_alarm / len(orientations)  # the budget is for the whole estimate
    for o in orientations:
        done = _orientation(
            d, valid, w, o, smooth, min_frequency, budget, min_stripe, max_components
        )
        if done is not None:
            components.extend(done[0])
            spectra[o] = done[1]
    components.sort(key=lambda c: -c.snr_db)
    return StripeEstimate(tuple(components), spectra)
