r"""Calibration of a fixed pattern from many frames (offline; torch and the standard library).

Model of frame ``t`` of a static scene ``S`` recorded at distance group ``k``::

    D_t(y, x) = (1 + gamma(x)) S_k(y, x) + c0(x) + r(y) + p(y, x) + n_t(y, x)

:func:`calibrate_fixed_pattern` estimates

* ``c`` / ``r``: per-column and per-row offsets, by the estimator of
  :func:`~tof_fpn_torch.runtime.destripe` (neighbour differences, robust means, local-linear
  high-pass over ``width`` columns, cross-validated shrinkage) applied to the robust temporal mean
  of each group, whose noise is ``1 / sqrt(T)`` of a frame's;
* ``gamma`` (``column_gain = 1 + gamma``), when the frames come from two or more groups (e.g. a
  flat wall at two or more distances): per column, the slope of the group's column offsets against
  the group's mean depth; ``c0`` is then the intercept at depth 0;
* ``p``: per-pixel offsets, only for a flat-field recording (``flat_field=True``: the scene is a
  smooth surface) with at least ``min_pixel_frames`` frames per group: the temporal mean minus the
  column and row offsets, a least-squares quadratic surface and its own ``width x width`` local
  mean, scaled by the cross-validated positive-part James-Stein factor
  ``clamp(<p_even, p_odd> / <p, p>, 0, 1)`` between the maps of the even and the odd frames (whose
  noise is independent; a standard-error formula from 9-16 frames underestimated it by ~30 %).

What it cannot identify: a constant (it belongs to the scene or to the range calibration); column,
row and pixel patterns slower than ``width`` (they are confounded with the scene's shape); per-pixel
offsets of a general scene (confounded with scene detail); gains from one distance (a gain times a
fixed scene is a fixed offset, which is how it is then corrected, exactly at that distance); depth-
or amplitude-dependent errors other than the linear column gain.

Files: :meth:`FixedPattern.to_arrays` / :meth:`FixedPattern.from_arrays` convert the pattern to
and from plain tensors and JSON-able fields (``frames``, ``groups``, ``levels``, ``width``,
``flat_field``, ``has_pixel``, ``has_gain``); the file layer stores them
(:mod:`tof_fpn_torch.io.patterns`, an ``.npz`` that ``numpy.load`` reads) and
:func:`tof_fpn_torch.clean.pattern.save_pattern` / :func:`~tof_fpn_torch.clean.pattern.read_pattern`
join the two.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import torch
import torch.nn.functional as F

from .. import constants as K
from ..runtime._destripe_core import column_offsets
from ..runtime.fixed_pattern import FixedPatternCorrection
from ..runtime.noise import mad_to_sigma
from ..runtime.validity import valid_mask

__all__ = ["MIN_PIXEL_FRAMES", "FixedPattern", "calibrate_fixed_pattern", "temporal_mean"]

#: :func:`calibrate_fixed_pattern` calibrates per-pixel offsets (flat field) only from at least this
#: many frames per group: a pixel's standard error is then at most a third of one frame's noise.
MIN_PIXEL_FRAMES: int = 9


@dataclass
class FixedPattern:
    """A calibrated fixed pattern (module docstring); tensors float64 on the CPU.

    Attributes:
        column_offset: (W,) ``c0``, depth units.
        row_offset: (H,).
        pixel_offset: (H, W) or None (not calibrated).
        column_gain: (W,) ``1 + gamma`` or None (not calibrated).
        column_se: (W,) standard error of ``column_offset`` from the temporal scatter.
        frames: number of frames used; groups: number of distance groups; levels: their mean
            depths; width: the high-pass width; flat_field: whether pixels were calibrated as such.
    """

    column_offset: torch.Tensor
    row_offset: torch.Tensor
    pixel_offset: torch.Tensor | None = None
    column_gain: torch.Tensor | None = None
    column_se: torch.Tensor | None = None
    frames: int = 0
    groups: int = 1
    levels: list[float] = field(default_factory=list)
    width: int = K.DESTRIPE_WIDTH
    flat_field: bool = False

    @property
    def shape(self) -> tuple[int, int]:
        return (self.row_offset.numel(), self.column_offset.numel())

    def offset_map(self) -> torch.Tensor:
        """(H, W) total offset ``c0(x) + r(y) + p(y, x)``."""
        o = self.column_offset[None, :] + self.row_offset[:, None]
        return o if self.pixel_offset is None else o + self.pixel_offset

    def module(self) -> FixedPatternCorrection:
        """The run-time :class:`~tof_fpn_torch.runtime.FixedPatternCorrection` of this pattern."""
        return FixedPatternCorrection(
            self.column_offset,
            self.row_offset,
            self.pixel_offset,
            self.column_gain,
            height=self.shape[0],
        )

    def to_arrays(self) -> tuple[dict[str, torch.Tensor], dict]:
        """``(arrays, meta)``: the pattern as float64 tensors (``pixel_offset`` zeros and
        ``column_gain`` ones when not calibrated) and its other fields as JSON-able values, what
        :func:`tof_fpn_torch.io.patterns.write_pattern_file` stores (module docstring)."""
        h, w = self.shape
        meta = {
            "frames": int(self.frames),
            "groups": int(self.groups),
            "levels": [float(v) for v in self.levels],
            "width": int(self.width),
            "flat_field": bool(self.flat_field),
            "has_pixel": self.pixel_offset is not None,
            "has_gain": self.column_gain is not None,
        }
        arrays = {
            "column_offset": self.column_offset,
            "row_offset": self.row_offset,
            "pixel_offset": torch.zeros(h, w) if self.pixel_offset is None else self.pixel_offset,
            "column_gain": torch.ones(w) if self.column_gain is None else self.column_gain,
            "column_se": torch.zeros(w) if self.column_se is None else self.column_se,
        }
        return {k: t.detach().double().cpu() for k, t in arrays.items()}, meta

    @classmethod
    def from_arrays(cls, arrays: dict[str, torch.Tensor], meta: dict) -> FixedPattern:
        """The pattern of :meth:`to_arrays`' ``(arrays, meta)`` (as
        :func:`tof_fpn_torch.io.patterns.read_pattern_file` returns them)."""
        return cls(
            column_offset=arrays["column_offset"],
            row_offset=arrays["row_offset"],
            pixel_offset=arrays["pixel_offset"] if meta["has_pixel"] else None,
            column_gain=arrays["column_gain"] if meta["has_gain"] else None,
            column_se=arrays.get("column_se"),
            frames=meta["frames"],
            groups=meta["groups"],
            levels=meta["levels"],
            width=meta["width"],
            flat_field=meta["flat_field"],
        )


def temporal_mean(
    frames: torch.Tensor, amplitudes: torch.Tensor | None = None, clip: float = K.DESTRIPE_CLIP
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Robust temporal mean of (T, 1, H, W) frames: ``(mean, se, valid)``, each (1, 1, H, W).

    Per pixel: the mean of the valid frames within ``clip`` robust sigmas (MAD) of their median;
    ``se`` its standard error (inlier scatter / sqrt(count)); ``valid`` where at least half of the
    frames were valid (elsewhere ``mean`` is NaN)."""
    v = valid_mask(frames, amplitudes)
    x = torch.where(v, frames.double(), math.nan)
    med = torch.nanmedian(x, dim=0, keepdim=True).values
    mad = mad_to_sigma(torch.nanmedian((x - med).abs(), dim=0, keepdim=True).values, 1)
    inl = v & ((x - med).abs() <= clip * mad.clamp_min(1e-12) + 1e-12 * med.abs())
    inl = inl | (v & (mad <= 0))
    n = inl.sum(0, keepdim=True).double()
    s = torch.where(inl, x, 0.0).sum(0, keepdim=True)
    mean = s / n.clamp_min(1.0)
    var = torch.where(inl, (x - mean) ** 2, 0.0).sum(0, keepdim=True) / (n - 1).clamp_min(1.0)
    ok = v.sum(0, keepdim=True) * 2 >= frames.shape[0]
    mean = torch.where(ok & (n > 0), mean, math.nan)
    return mean, torch.sqrt(var / n.clamp_min(1.0)), ok & (n > 0)


def _offsets(mean: torch.Tensor, valid: torch.Tensor, width: int, clip: float):
    """Column then row offsets of a (1, 1, H, W) map (the destripe estimator, ``"local"``)."""
    args = (width, clip, "local", K.DESTRIPE_LOCAL_WIDTH, K.DESTRIPE_PILOT_ROWS)
    x = torch.where(valid, mean, 0.0)
    col, _ = column_offsets(x, valid, *args)
    x = x - col[:, :, None, :]
    row, _ = column_offsets(x.transpose(-1, -2), valid.transpose(-1, -2), *args)
    return col[0, 0], row[0, 0]


def _check_frames(frames, amplitudes, groups) -> list[int]:
    if not isinstance(frames, torch.Tensor) or frames.dim() != 4 or frames.shape[1] != 1:
        raise ValueError(
            f"frames must be a (T, 1, H, W) tensor, got {getattr(frames, 'shape', type(frames))}"
        )
    if not frames.is_floating_point():
        raise ValueError(f"frames must be floating point, got dtype {frames.dtype}")
    t = frames.shape[0]
    if t < 2 or frames.shape[2] < 2 or frames.shape[3] < 2:
        raise ValueError(f"frames must hold T >= 2 frames of H, W >= 2, got {list(frames.shape)}")
    if amplitudes is not None and (
        not isinstance(amplitudes, torch.Tensor) or amplitudes.shape != frames.shape
    ):
        raise ValueError(
            f"amplitudes must be a tensor of the frames' shape {list(frames.shape)}, got "
            f"{getattr(amplitudes, 'shape', type(amplitudes))}"
        )
    if groups is None:
        return [0] * t
    labels = [int(g) for g in groups]
    if len(labels) != t:
        raise ValueError(f"groups must give one label per frame ({t}), got {len(labels)}")
    for g in sorted(set(labels)):
        if labels.count(g) < 2:
            raise ValueError(f"every group needs >= 2 frames, group {g} has {labels.count(g)}")
    return labels


def calibrate_fixed_pattern(
    frames: torch.Tensor,
    amplitudes: torch.Tensor | None = None,
    *,
    groups: Sequence[int] | None = None,
    flat_field: bool = False,
    width: int = K.DESTRIPE_WIDTH,
    clip: float = K.DESTRIPE_CLIP,
    min_pixel_frames: int = MIN_PIXEL_FRAMES,
) -> FixedPattern:
    """Estimate the fixed pattern of (T, 1, H, W) ``frames`` of a static scene (module docstring).

    Args:
        frames: depth frames; invalid pixels (valid_mask) are left out per pixel and frame.
        amplitudes: optional (T, 1, H, W), extends the validity rule.
        groups: optional label per frame: frames with the same label show the same scene (e.g. a
            wall at one distance); two or more groups at different mean depths calibrate the
            column gain.
        flat_field: the scene is a smooth surface: also calibrate per-pixel offsets.
        width: high-pass width of the column / row / pixel patterns (int >= 3).
        clip: robust trimming threshold in sigmas.
        min_pixel_frames: per-pixel offsets need at least this many frames (per group).

    Raises:
        ValueError: bad shapes, fewer than 2 frames per group, groups at equal depths.
    """
    labels = _check_frames(frames, amplitudes, groups)
    if isinstance(width, bool) or not isinstance(width, int) or width < 3:
        raise ValueError(f"width must be an int >= 3, got {width!r}")
    frames = frames.detach().cpu().double()
    amplitudes = None if amplitudes is None else amplitudes.detach().cpu().double()
    cols, rows, levels, counts, ses, valids = [], [], [], [], [], []
    for g in sorted(set(labels)):
        idx = torch.tensor([i for i, lab in enumerate(labels) if lab == g])
        amp = None if amplitudes is None else amplitudes[idx]
        mean, se, valid = temporal_mean(frames[idx], amp, clip)
        col, row = _offsets(mean, valid, width, clip)
        cols.append(col)
        rows.append(row)
        levels.append(float(mean[valid].mean()) if bool(valid.any()) else 0.0)
        counts.append(idx.numel())
        ses.append(se)
        valids.append(valid)
    weights = torch.tensor(counts, dtype=torch.float64)
    weights = weights / weights.sum()
    row = sum(w * r for w, r in zip(weights, rows, strict=True))
    se_col = _column_se(ses, valids, counts)
    gain = None
    if len(cols) == 1:
        col = cols[0]
    else:
        lv = torch.tensor(levels, dtype=torch.float64)
        dl = lv - (weights * lv).sum()
        if float((weights * dl * dl).sum()) <= 1e-12 * max(1.0, float(lv.abs().max()) ** 2):
            raise ValueError(
                f"the groups must be at different mean depths to calibrate a gain, got {levels}"
            )
        c = torch.stack(cols)  # (G, W)
        cbar = (weights[:, None] * c).sum(0)
        gamma = (weights[:, None] * dl[:, None] * (c - cbar)).sum(0) / (weights * dl * dl).sum()
        level = float((weights * lv).sum())
        col = cbar - gamma * level  # intercept at depth 0
        gain = 1.0 + gamma
    pixel = None
    if flat_field and min(counts) >= min_pixel_frames:
        pixel = _pixel_offsets(frames, amplitudes, labels, cols, rows, weights, width, clip)
    return FixedPattern(
        column_offset=col,
        row_offset=row,
        pixel_offset=pixel,
        column_gain=gain,
        column_se=se_col,
        frames=frames.shape[0],
        groups=len(cols),
        levels=levels,
        width=width,
        flat_field=bool(flat_field),
    )


def _column_se(ses, valids, counts) -> torch.Tensor:
    """Standard error of a column offset: the pixel standard errors averaged down the column."""
    out = []
    for se, v in zip(ses, valids, strict=True):
        n = v.sum(2).double().clamp_min(1.0)
        out.append(torch.sqrt(torch.where(v, se * se, 0.0).sum(2) / (n * n))[0, 0])
    w = torch.tensor(counts, dtype=torch.float64)
    return torch.sqrt(sum((wi / w.sum()) ** 2 * s * s for wi, s in zip(w, out, strict=True)))


def _box2d(x: torch.Tensor, width: int) -> torch.Tensor:
    y = F.avg_pool2d(x, width, 1, width // 2, count_include_pad=True)
    return y[..., : x.shape[-2], : x.shape[-1]]


def _quadratic_fit(z: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Least-squares quadratic surface in (y, x) through the valid pixels of (H, W) ``z``: the
    flat-field target's shape, removed before the local mean so that no border is biased."""
    h, w = z.shape
    yy, xx = torch.meshgrid(
        torch.linspace(-1.0, 1.0, h, dtype=torch.float64),
        torch.linspace(-1.0, 1.0, w, dtype=torch.float64),
        indexing="ij",
    )
    basis = torch.stack([torch.ones_like(xx), xx, yy, xx * xx, xx * yy, yy * yy], -1)
    a = basis[v]
    coef = torch.linalg.lstsq(a, z[v][:, None]).solution
    return (basis @ coef)[..., 0]


def _residual(m: torch.Tensor, v: torch.Tensor, c, r, width: int) -> torch.Tensor:
    """(H, W) flat-field residual: ``m`` minus the column and row offsets, a quadratic surface
    and its own ``width x width`` local mean (0 at invalid pixels)."""
    res = torch.where(v, m - c[None, None, None, :] - r[None, None, :, None], 0.0)
    res = torch.where(v, res - _quadratic_fit(res[0, 0], v[0, 0]), 0.0)
    local = _box2d(res, width) / _box2d(v.double(), width).clamp_min(1e-12)
    return torch.where(v, res - local, 0.0)[0, 0]


def _pixel_offsets(frames, amplitudes, labels, cols, rows, weights, width, clip) -> torch.Tensor:
    """Flat field: per-pixel offsets (the residual of each group's temporal mean, averaged over the
    groups), scaled by the cross-validated positive-part James-Stein factor
    ``clamp(<p_even, p_odd> / <p, p>, 0, 1)`` between the residuals of the even and the odd
    frames, whose noise is independent (as in :func:`~tof_fpn_torch.runtime.destripe`)."""
    h, w = frames.shape[-2:]
    acc = [torch.zeros(h, w, dtype=torch.float64) for _ in range(3)]
    cnt = [torch.zeros(h, w, dtype=torch.float64) for _ in range(3)]
    for wt, g, c, r in zip(weights, sorted(set(labels)), cols, rows, strict=True):
        idx = [i for i, lab in enumerate(labels) if lab == g]
        for k, sel in enumerate((idx, idx[0::2], idx[1::2])):
            t = torch.tensor(sel)
            amp = None if amplitudes is None else amplitudes[t]
            m, _, v = temporal_mean(frames[t], amp, clip)
            acc[k] = acc[k] + wt * _residual(m, v, c, r, width)
            cnt[k] = cnt[k] + wt * v[0, 0].double()
    ok = (cnt[0] > 0) & (cnt[1] > 0) & (cnt[2] > 0)
    p, even, odd = (
        torch.where(ok, a / n.clamp_min(1e-12), 0.0) for a, n in zip(acc, cnt, strict=True)
    )
    energy = float((p * p).sum())
    factor = min(1.0, max(0.0, float((even * odd).sum()) / energy)) if energy > 0 else 0.0
    return factor * p
