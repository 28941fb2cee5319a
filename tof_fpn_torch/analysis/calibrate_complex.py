r"""Calibration of a complex-domain fixed pattern from many frames (offline; torch and stdlib).

A read-out offset is additive in the raw complex signal ``z = A e^{j phi}``,
``phi = 4 pi f D / c_L``: frame ``t`` of any scene is ``z_t(y, x) = s_t(y, x) + c(x) [+ r(y)] +
noise`` with a complex column offset ``c`` the same in every frame. :func:`calibrate_complex_pattern`
estimates ``c`` (and ``r`` with ``rows=True``) from T frames, of one static scene or of different
scenes:

1. **Pixels.** Valid pixels (:func:`~tof_fpn_torch.runtime.valid_mask`) no brighter than
   ``amplitude_cap`` times their frame's median amplitude: the bright ones carry the strongest
   scene texture, and an offset barely moves their depth (the error is ``|c| / A``).
2. **Differences** ``g = z(y, x + 1) - z(y, x)`` of usable pairs in every row of every frame: the
   offset enters every row as ``c(x + 1) - c(x)``; the scene enters as edges (rare per pair) and as
   amplitude texture, which lies along the pair's own phasor ``u``.
3. **Weights.** The component of ``g`` along ``u`` is weighted ``1 - beta``,
   ``beta = A^2 / (A^2 + (k sigma)^2)`` (``k = texture_k``, ``sigma`` the robust per-channel noise
   of ``z``): a bright pixel informs only the direction across its phasor (its depth), a dark one
   both (where the noise, not the texture, dominates).
4. **Robust pair offsets**, per half of the rows: the weighted least-squares solution of the 2 x 2
   normal equations ``sum (I - beta u u^T) d = sum (I - beta u u^T) g`` over the differences
   within ``clip`` sigmas of a pilot (per-pair median, then twice the solution itself), with a
   ridge of ``ridge`` times the pixel count: a direction no pixel sees (a column of one phase) is
   left at ~0 and does not matter for such a column. Its noise falls as ``1 / sqrt(T rows)``.
5. **Profile**: pair offsets far outside their population dropped (edges most rows share, as in
   :func:`~tof_fpn_torch.runtime.destripe`), integrated, high-passed over ``width`` columns (at most
   a quarter of the line: slower offsets are confounded with the scene's shape).
6. **Shrinkage** by cross-validation: octave bands and windows of the profile of all rows scaled
   by ``clamp((<p_top, p_bottom> - z sd0) / <p, p>, 0, 1)`` (the destriper's rule) between the
   profiles of the top and the bottom half of the rows, each pooled over all frames. The halves'
   noise is independent (as between the even and the odd frames) and structure confined to one
   half is not shared either, so a camera without a pattern gets ~0.

Then zero mean over the usable pixels. Rows (``rows=True``): the same on the transposed frames after
the columns are removed. What it cannot identify: a constant offset; offsets slower than ``width``;
the component of an offset along the phasor of a column that has one phase in every frame (it does
not move that column's depth); a vertical amplitude texture of dark pixels in the same columns of
every frame.

File: :meth:`ComplexPattern.to_arrays` / :meth:`ComplexPattern.from_arrays` convert the pattern
to and from plain tensors (``column_offset_re``, ``column_offset_im``, ``row_offset_re``,
``row_offset_im``, ``column_pixels``) and JSON-able fields; the file layer stores them
(:mod:`tof_fpn_torch.io.patterns`, an ``.npz`` that ``numpy.load`` reads) and
:func:`tof_fpn_torch.clean.pattern.save_pattern` / :func:`~tof_fpn_torch.clean.pattern.read_pattern`
join the two.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from .. import constants as K
from ..runtime import _destripe_core as core
from ..runtime._phasor import metres_per_radian, phasor
from ..runtime.complex_pattern import ComplexPatternCorrection
from ..runtime.noise import clipped_rms_scale, scale_moment
from ..runtime.validity import valid_mask

__all__ = [
    "AMPLITUDE_CAP",
    "RIDGE",
    "TEXTURE_K",
    "WIDTH",
    "ComplexPattern",
    "calibrate_complex_pattern",
]

#: Width (columns) of the high-pass of the calibrated profile (at most a quarter of the line is
#: used): wider than the single frame's ``DESTRIPE_WIDTH``, as T frames average the scene's slow
#: column profile down (51 against 31 on the raw simulator: +0.14 dB over the 16 calibrations of
#: docs/destripe.md, +0.5 dB at the darkest level, -0.1 dB on the bright planar scene).
WIDTH: int = 51
#: A pixel brighter than this multiple of its frame's median amplitude is left out of the estimate
#: (its scene texture is strongest and a read-out offset barely moves its depth: the error is
#: ``|o| / A``); 2: measured best of 1.5 - 3 on the raw simulator (docs/destripe.md).
AMPLITUDE_CAP: float = 2.0
#: The component of a pixel's column difference along its own phasor (where amplitude texture
#: lies) is weighted ``1 - beta``, ``beta = A^2 / (A^2 + (k sigma)^2)`` with ``sigma`` the
#: per-channel noise of ``z`` and ``k`` this value (2 - 5 measured equally good; 10 lets the
#: painted wall of the bright planar scene in).
TEXTURE_K: float = 3.0
#: Ridge (share of the pixel count) on the 2 x 2 normal equations of each column pair: a direction
#: seen by fewer pixels than this share (a column of one phase) is left at ~0.
RIDGE: float = 0.02


@dataclass
class ComplexPattern:
    """A calibrated complex fixed pattern (module docstring); tensors float64 on the CPU.

    Attributes:
        column_offset_re, column_offset_im: (W,) complex column offsets ``c``, amplitude units.
        modulation_frequency_hz: the ``f`` the frames were converted with.
        row_offset_re, row_offset_im: (H,) or None (not calibrated).
        column_pixels: (W,) difference pairs used per column (both neighbours' pairs).
        frames, width, amplitude_cap, texture_k: the calibration's inputs.
        noise_sigma: robust per-channel noise of ``z`` in one frame (amplitude units).
        shrink_factor: mean cross-validated factor of the column profile (1: all kept, 0: none).
        focal_length_px: the frames' depth is ``Z`` along the optical axis of a pinhole with
            this focal length (pixels); None: radial distance
            (:class:`~tof_fpn_torch.runtime.ComplexPatternCorrection`).
        amplitude_floor: pixels darker than this are corrected as at this amplitude (None: no
            floor).
    """

    column_offset_re: torch.Tensor
    column_offset_im: torch.Tensor
    modulation_frequency_hz: float
    row_offset_re: torch.Tensor | None = None
    row_offset_im: torch.Tensor | None = None
    column_pixels: torch.Tensor | None = None
    frames: int = 0
    width: int = WIDTH
    amplitude_cap: float = AMPLITUDE_CAP
    texture_k: float = TEXTURE_K
    noise_sigma: float = 0.0
    shrink_factor: float = 0.0
    height: int = -1
    focal_length_px: float | None = None
    amplitude_floor: float | None = None

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) of the calibration frames."""
        return (self.height, self.column_offset_re.numel())

    def module(self, wrap: bool = True) -> ComplexPatternCorrection:
        """The run-time :class:`~tof_fpn_torch.runtime.ComplexPatternCorrection` of this pattern
        (for frames of the calibrated width; with rows, also of the calibrated height)."""
        return ComplexPatternCorrection(
            self.column_offset_re,
            self.column_offset_im,
            self.modulation_frequency_hz,
            self.row_offset_re,
            self.row_offset_im,
            wrap=wrap,
            focal_length_px=self.focal_length_px,
            amplitude_floor=self.amplitude_floor,
        )

    def to_arrays(self) -> tuple[dict[str, torch.Tensor], dict]:
        """``(arrays, meta)``: the pattern as float64 tensors (rows zeros when not calibrated)
        and its other fields as JSON-able values, what
        :func:`tof_fpn_torch.io.patterns.write_pattern_file` stores (module docstring)."""
        w = self.column_offset_re.numel()
        h = max(self.height, 0)
        has_rows = self.row_offset_re is not None
        meta = {
            "modulation_frequency_hz": float(self.modulation_frequency_hz),
            "frames": int(self.frames),
            "height": int(self.height),
            "width": int(self.width),
            "amplitude_cap": float(self.amplitude_cap),
            "texture_k": float(self.texture_k),
            "noise_sigma": float(self.noise_sigma),
            "shrink_factor": float(self.shrink_factor),
            "has_rows": has_rows,
        }
        # set only when used: a plain pattern's file keeps its layout
        for key in ("focal_length_px", "amplitude_floor"):
            if getattr(self, key) is not None:
                meta[key] = float(getattr(self, key))
        zeros = torch.zeros(h, dtype=torch.float64)
        arrays = {
            "column_offset_re": self.column_offset_re,
            "column_offset_im": self.column_offset_im,
            "row_offset_re": self.row_offset_re if has_rows else zeros,
            "row_offset_im": self.row_offset_im if has_rows else zeros,
            "column_pixels": torch.zeros(w) if self.column_pixels is None else self.column_pixels,
        }
        return {k: t.detach().double().cpu() for k, t in arrays.items()}, meta

    @classmethod
    def from_arrays(cls, arrays: dict[str, torch.Tensor], meta: dict) -> ComplexPattern:
        """The pattern of :meth:`to_arrays`' ``(arrays, meta)`` (as
        :func:`tof_fpn_torch.io.patterns.read_pattern_file` returns them)."""
        rows = meta["has_rows"]
        return cls(
            column_offset_re=arrays["column_offset_re"],
            column_offset_im=arrays["column_offset_im"],
            modulation_frequency_hz=meta["modulation_frequency_hz"],
            row_offset_re=arrays["row_offset_re"] if rows else None,
            row_offset_im=arrays["row_offset_im"] if rows else None,
            column_pixels=arrays.get("column_pixels"),
            frames=meta["frames"],
            width=meta["width"],
            amplitude_cap=meta["amplitude_cap"],
            texture_k=meta["texture_k"],
            noise_sigma=meta["noise_sigma"],
            shrink_factor=meta["shrink_factor"],
            height=meta["height"],
            focal_length_px=meta.get("focal_length_px"),
            amplitude_floor=meta.get("amplitude_floor"),
        )


def _solve(g, inl, beta, u, ridge):
    """Weighted least-squares pair offsets (2, C) from differences ``g`` (T, 2, R, C) at the
    inliers ``inl`` (T, 1, R, C) with weights ``I - beta u u^T``; also the pixel counts (C,)."""
    i = inl.double()
    cnt = i.sum((0, 2))[0]
    bu = beta * i
    uxx = (bu * u[:, :1] * u[:, :1]).sum((0, 2))[0]
    uyy = (bu * u[:, 1:] * u[:, 1:]).sum((0, 2))[0]
    uxy = (bu * u[:, :1] * u[:, 1:]).sum((0, 2))[0]
    wg = (g - beta * u * (u * g).sum(1, keepdim=True)) * i
    b = wg.sum((0, 2))  # (2, C)
    mxx = cnt - uxx + ridge * cnt
    myy = cnt - uyy + ridge * cnt
    mxy = -uxy
    det = mxx * myy - mxy * mxy
    ok = det > 0
    det = torch.where(ok, det, 1.0)
    dx = torch.where(ok, (myy * b[0] - mxy * b[1]) / det, 0.0)
    dy = torch.where(ok, (mxx * b[1] - mxy * b[0]) / det, 0.0)
    return torch.stack([dx, dy]), cnt


def _nanmedian_pairs(g: torch.Tensor, ok: torch.Tensor) -> torch.Tensor:
    """Per pair (column of ``g``) and channel: the median over frames and rows of the usable
    differences, (1, 2, 1, C) (0 where there is none)."""
    t, k, r, c = g.shape
    x = torch.where(ok, g, math.nan).permute(1, 3, 0, 2).reshape(k, c, t * r)
    return torch.nan_to_num(torch.nanmedian(x, dim=-1).values, nan=0.0).view(1, k, 1, c)


def _line_offsets(z, v, width, clip, texture_k, ridge, local_width):
    """Offsets (2, W) along the last dim of (T, 2, H, W) ``z`` (usable pixels ``v``), the factor
    of the shrinkage, the pairs per column (W,) and the noise sigma (module docstring)."""
    h, w = z.shape[2], z.shape[3]
    half = h // 2
    g = z[..., 1:] - z[..., :-1]
    ok = v[..., 1:] & v[..., :-1]
    m = z[..., 1:] + z[..., :-1]
    mag = torch.sqrt((m * m).sum(1, keepdim=True))
    u = torch.where(mag > 0, m / mag.clamp_min(1e-300), 0.0)
    n = torch.cat([-u[:, 1:], u[:, :1]], 1)  # across the phasor
    pilot = _nanmedian_pairs(g, ok)
    across = ((g - pilot) * n).sum(1, keepdim=True).abs()
    moment = scale_moment(1, clip)
    sig_g = clipped_rms_scale(across.reshape(1, 1, 1, -1), ok.reshape(1, 1, 1, -1), clip, moment, 1)
    sig_g = float(sig_g[0])  # noise of one channel of g: sqrt(2) times that of z
    amp2 = 0.25 * mag * mag
    ref2 = (texture_k * sig_g) ** 2 / 2.0
    beta = torch.where(mag > 0, amp2 / (amp2 + ref2) if ref2 > 0 else torch.ones_like(amp2), 0.0)
    lim2 = (clip * sig_g) ** 2
    halves = (slice(0, half), slice(half, h))
    sols, cnts = [], []
    for _ in range(2):
        e = g - pilot
        e_al = (e * u).sum(1, keepdim=True)
        e_ac = (e * n).sum(1, keepdim=True)
        inl = ok & (e_ac * e_ac <= lim2) & ((1.0 - beta) * e_al * e_al <= lim2)
        sols, cnts = [], []
        for sl in halves:
            d, cnt = _solve(g[:, :, sl], inl[:, :, sl], beta[:, :, sl], u[:, :, sl], ridge)
            sols.append(d)
            cnts.append(cnt)
        tot = (cnts[0] + cnts[1]).clamp_min(1.0)
        pilot = ((cnts[0] * sols[0] + cnts[1] * sols[1]) / tot).view(1, 2, 1, w - 1)
    pairs = core._reject_steps(torch.stack(sols), K.DESTRIPE_STEP_CLIP)  # (2, 2, W - 1)
    width = max(3, min(width, w // 4))
    p = core._profile(pairs, width)
    p_top, p_bot = p[:1], p[1:]
    p_all = (half * p_top + (h - half) * p_bot) / h
    out, factors = core.band_shrink(p_top, p_bot, p_all, width, True, local_width)
    used = torch.nn.functional.pad(cnts[0] + cnts[1], (1, 0)) + torch.nn.functional.pad(
        cnts[0] + cnts[1], (0, 1)
    )
    count = v.sum((0, 2), dtype=torch.float64).view(1, 1, w)
    out = core._zero_mean(out, count)
    return out[0], float(factors.mean()), used, sig_g / math.sqrt(2.0)


def _check(frames, amplitudes, f, width, clip, cap, k, ridge) -> None:
    for name, t in (("frames", frames), ("amplitudes", amplitudes)):
        if not isinstance(t, torch.Tensor) or t.dim() != 4 or t.shape[1] != 1:
            raise ValueError(
                f"{name} must be a (T, 1, H, W) tensor, got {getattr(t, 'shape', type(t))}"
            )
        if not t.is_floating_point():
            raise ValueError(f"{name} must be floating point, got dtype {t.dtype}")
    if amplitudes.shape != frames.shape:
        raise ValueError(
            f"amplitudes must have the frames' shape {list(frames.shape)}, got "
            f"{list(amplitudes.shape)}"
        )
    if frames.shape[0] < 1 or frames.shape[2] < 4 or frames.shape[3] < 4:
        raise ValueError(f"frames must hold T >= 1 frames of H, W >= 4, got {list(frames.shape)}")
    if isinstance(f, bool) or not isinstance(f, (int, float)) or not 0 < f < math.inf:
        raise ValueError(f"modulation_frequency_hz must be a finite number > 0 (Hz), got {f!r}")
    if isinstance(width, bool) or not isinstance(width, int) or width < 3:
        raise ValueError(f"width must be an int >= 3 (columns), got {width!r}")
    for name, val, low in (("clip", clip, 0.0), ("amplitude_cap", cap, 0.0), ("texture_k", k, 0.0)):
        if isinstance(val, bool) or not isinstance(val, (int, float)) or not low < val < math.inf:
            raise ValueError(f"{name} must be a finite number > {low:g}, got {val!r}")
    if isinstance(ridge, bool) or not isinstance(ridge, (int, float)) or not 0 < ridge < math.inf:
        raise ValueError(f"ridge must be a finite number > 0, got {ridge!r}")


def calibrate_complex_pattern(
    frames: torch.Tensor,
    amplitudes: torch.Tensor,
    modulation_frequency_hz: float,
    *,
    rows: bool = False,
    width: int = WIDTH,
    clip: float = K.DESTRIPE_CLIP,
    amplitude_cap: float = AMPLITUDE_CAP,
    texture_k: float = TEXTURE_K,
    ridge: float = RIDGE,
    local_width: int = K.DESTRIPE_LOCAL_WIDTH,
) -> ComplexPattern:
    """Estimate the complex column (and row) offsets of the read-out from (T, 1, H, W) depth
    ``frames`` and their ``amplitudes`` (module docstring).

    Args:
        frames: depth frames (one static scene or different scenes, the same camera settings);
            invalid pixels (``valid_mask``) are left out per pixel and frame.
        amplitudes: (T, 1, H, W) amplitudes, in the units the run-time module will get.
        modulation_frequency_hz: ``f`` of ``phi = 4 pi f D / c_L``.
        rows: also estimate per-row offsets (after the columns).
        width: high-pass width of the profiles (int >= 3; at most a quarter of the line is used).
        clip: robust trimming threshold in sigmas.
        amplitude_cap: pixels brighter than this multiple of their frame's median amplitude are
            not used.
        texture_k: the along-phasor weight's amplitude scale, in noise sigmas.
        ridge: ridge of the 2 x 2 normal equations, as a share of the pixel count.
        local_width: window of the cross-validated shrinkage.

    Raises:
        ValueError: bad shapes or values (the message names the argument and what is allowed).
    """
    _check(
        frames, amplitudes, modulation_frequency_hz, width, clip, amplitude_cap, texture_k, ridge
    )
    if isinstance(local_width, bool) or not isinstance(local_width, int) or local_width < 3:
        raise ValueError(f"local_width must be an int >= 3 (columns), got {local_width!r}")
    d = frames.detach().cpu().double()
    a = amplitudes.detach().cpu().double()
    v = valid_mask(d, a)
    flat = torch.where(v, a, math.nan).reshape(a.shape[0], -1)
    med = torch.nan_to_num(torch.nanmedian(flat, dim=1).values, nan=0.0).view(-1, 1, 1, 1)
    v = v & (a <= amplitude_cap * med)
    scale = metres_per_radian(float(modulation_frequency_hz))
    z = phasor(torch.where(v, d, 0.0), torch.where(v, a, 0.0), scale)
    args = (width, float(clip), float(texture_k), float(ridge), local_width)
    col, factor, used, sigma = _line_offsets(z, v, *args)
    row = None
    if rows:
        zr = torch.where(v, z - col.view(1, 2, 1, -1), 0.0)
        row, _, _, _ = _line_offsets(zr.transpose(-1, -2), v.transpose(-1, -2), *args)
    return ComplexPattern(
        column_offset_re=col[0].clone(),
        column_offset_im=col[1].clone(),
        modulation_frequency_hz=float(modulation_frequency_hz),
        row_offset_re=None if row is None else row[0].clone(),
        row_offset_im=None if row is None else row[1].clone(),
        column_pixels=used,
        frames=int(frames.shape[0]),
        width=int(width),
        amplitude_cap=float(amplitude_cap),
        texture_k=float(texture_k),
        noise_sigma=sigma,
        shrink_factor=factor,
        height=int(frames.shape[2]),
    )
