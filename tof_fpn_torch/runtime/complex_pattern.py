r"""Correction of a calibrated complex fixed pattern (torch only; TorchScript and ONNX exportable).

A read-out offset is additive in the raw complex signal ``z = A e^{j phi}``, ``phi = 4 pi f D / c_L``,
so the depth error it causes depends on each pixel's amplitude and phase. A pattern calibrated
offline from many frames (:func:`tof_fpn_torch.analysis.calibrate_complex_pattern`) is removed as

    ``z' = z - c(x) - r(y)``,   ``D' = D + c_L / (4 pi f) angle(z' conj z)``

(re-wrapped into ``[0, c_L / 2f)`` when ``wrap``) with complex per-column offsets ``c`` and optional
per-row offsets ``r`` in amplitude units, held as a float64 buffer. The phase belongs to the radial
distance along each pixel's ray; a camera that writes depth along the optical axis (``Z``) measured
``Z |ray|`` (a pinhole with the principal point at the frame centre, focal length ``f_px``:
``|ray| = sqrt(1 + ((x - x_c)^2 + (y - y_c)^2) / f_px^2)``), and the correction is computed on that
distance and divided by ``|ray|`` again. Invalid pixels
(:func:`~tof_fpn_torch.runtime.valid_mask`) come out bit-identical, and where the correction would
make a valid depth invalid (``<= 0``) the input is kept. Nothing is estimated at run time.
"""

# no `from __future__ import annotations`: TorchScript reads the class-level attribute types below
import math

import torch

from ._checks import check_image, check_same_shape
from ._phasor import depth_from_phase_change, metres_per_radian, phasor, ray_norm
from .stage import Stage, empty_record
from .validity import valid_mask

__all__ = ["ComplexPatternCorrection"]


def _vector(v, name: str, n: int) -> torch.Tensor:
    t = torch.as_tensor(v, dtype=torch.float64).detach().clone().cpu()
    if t.dim() != 1 or (n >= 0 and t.numel() != n):
        want = "a 1-D tensor" if n < 0 else f"a 1-D tensor of {n} values"
        raise ValueError(f"{name} must be {want}, got shape {list(t.shape)}")
    if not bool(torch.isfinite(t).all()):
        raise ValueError(f"{name} must be finite, got {int((~torch.isfinite(t)).sum())} NaN/inf")
    return t


class ComplexPatternCorrection(Stage):
    r"""Remove a calibrated complex fixed pattern: ``z' = z - c(x) - r(y)``, depth by the phase
    change.

    Args:
        column_offset_re, column_offset_im: (W,) real and imaginary parts of ``c``, amplitude units
            (the units of the ``amplitude`` input).
        modulation_frequency_hz: ``f`` (finite > 0).
        row_offset_re, row_offset_im: optional (H,) parts of ``r`` (both or neither).
        wrap: re-wrap the output into ``[0, c_L / 2f)`` (single-frequency depth); False keeps the
            input's branch.
        height: H when only column offsets are given (None: any height is accepted).
        focal_length_px: the depth is ``Z`` along the optical axis of a pinhole camera with this
            focal length (pixels, finite > 0; principal point at the frame centre); None: the
            depth is the radial distance.
        amplitude_floor: pixels darker than this (amplitude units, finite > 0) are corrected as
            if they had this amplitude (the model an offset learned with a floored ``1 / A`` was
            fitted with; a dark pixel's phase is not turned further); None: no floor.

    Shape:
        - depth, amplitude: (B, C, H, W) float with the calibrated W (and H when rows are
          calibrated or ``height`` is given).
        - Output: same shape, dtype and device as depth; invalid pixels unchanged.

    Example:
        >>> f = 20e6
        >>> m = ComplexPatternCorrection([0.0, 3.0], [0.0, 0.0], f)
        >>> d = torch.full((1, 1, 1, 2), 1.0)
        >>> a = torch.full((1, 1, 1, 2), 10.0)
        >>> out = m(d, a)  # column 1: z - 3 turns the phase of 10 e^{j phi} away from 0
        >>> bool(out[0, 0, 0, 0] == 1.0), bool(out[0, 0, 0, 1] > 1.0)
        (True, True)
    """

    height: int
    width: int
    modulation_frequency_hz: float
    scale: float
    wrap: bool
    focal_length_px: float
    amplitude_floor: float

    def __init__(
        self,
        column_offset_re,
        column_offset_im,
        modulation_frequency_hz: float,
        row_offset_re=None,
        row_offset_im=None,
        wrap: bool = True,
        height: int | None = None,
        focal_length_px: float | None = None,
        amplitude_floor: float | None = None,
    ) -> None:
        super().__init__()
        f = modulation_frequency_hz
        if isinstance(f, bool) or not isinstance(f, (int, float)) or not 0 < f < math.inf:
            raise ValueError(f"modulation_frequency_hz must be a finite number > 0 (Hz), got {f!r}")
        re = _vector(column_offset_re, "column_offset_re", -1)
        w = re.numel()
        im = _vector(column_offset_im, "column_offset_im", w)
        if (row_offset_re is None) != (row_offset_im is None):
            raise ValueError("row_offset_re and row_offset_im must be given together")
        fl = focal_length_px
        if fl is not None and (
            isinstance(fl, bool) or not isinstance(fl, (int, float)) or not 0 < fl < math.inf
        ):
            raise ValueError(
                f"focal_length_px must be a finite number > 0 (pixels) or None, got {fl!r}"
            )
        fa = amplitude_floor
        if fa is not None and (
            isinstance(fa, bool) or not isinstance(fa, (int, float)) or not 0 < fa < math.inf
        ):
            raise ValueError(f"amplitude_floor must be a finite number > 0 or None, got {fa!r}")
        h = -1 if height is None else int(height)
        if height is not None and h < 1:
            raise ValueError(f"height must be an int >= 1, got {height!r}")
        offset = torch.stack([re, im]).view(1, 2, 1, w)
        if row_offset_re is not None:
            rre = _vector(row_offset_re, "row_offset_re", h)
            h = rre.numel()
            rim = _vector(row_offset_im, "row_offset_im", h)
            offset = offset + torch.stack([rre, rim]).view(1, 2, h, 1)
        self.height = h
        self.width = w
        self.modulation_frequency_hz = float(f)
        self.scale = metres_per_radian(float(f))
        self.wrap = bool(wrap)
        self.focal_length_px = -1.0 if fl is None else float(fl)  # -1: radial distance
        self.amplitude_floor = -1.0 if fa is None else float(fa)  # -1: none
        self.register_buffer("offset", offset)  # (1, 2, 1 or H, W) float64

    def extra_repr(self) -> str:
        h = "any" if self.height < 0 else str(self.height)
        return (
            f"height={h}, width={self.width}, offset_rows={self.offset.shape[2]}, "
            f"modulation_frequency_hz={self.modulation_frequency_hz:g}, wrap={self.wrap}, "
            f"focal_length_px={self.focal_length_px if self.focal_length_px > 0 else None}, "
            f"amplitude_floor={self.amplitude_floor if self.amplitude_floor > 0 else None}"
        )

    def _run(
        self, depth: torch.Tensor, amplitude: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        check_image(depth, "depth")
        if amplitude is None:
            raise ValueError(
                "amplitude is required: the pattern is complex (A e^{j phi}); got None"
            )
        check_image(amplitude, "amplitude")
        check_same_shape(amplitude, depth, "amplitude", "depth")
        if depth.shape[-1] != self.width or (self.height >= 0 and depth.shape[-2] != self.height):
            h = "H" if self.height < 0 else str(self.height)
            raise ValueError(
                f"depth must have the calibrated size (..., {h}, {self.width}), got shape "
                f"{list(depth.shape)}"
            )
        b, c, h, w = depth.shape
        low = depth.dtype == torch.float16 or depth.dtype == torch.bfloat16
        work = torch.float32 if low else depth.dtype
        x = depth.to(work).reshape(b * c, 1, h, w)
        amp = amplitude.to(work).reshape(b * c, 1, h, w)
        valid = valid_mask(x, amp)
        zero = torch.zeros_like(x)
        ray = torch.ones(1, dtype=work, device=x.device)
        if self.focal_length_px > 0:
            ray = ray_norm(h, w, self.focal_length_px, work, x.device)
        r = x * ray  # the radial distance
        if self.amplitude_floor > 0:
            amp = amp.clamp_min(self.amplitude_floor)
        z = phasor(torch.where(valid, r, zero), torch.where(valid, amp, zero), self.scale)
        zc = z - self.offset.to(work)
        y = depth_from_phase_change(r, z, zc, self.scale, self.wrap) / ray
        # invalid pixels come out bit-identical; a valid pixel never comes out invalid
        y = torch.where(valid & valid_mask(y), y, x)
        out = torch.where(valid.reshape(b, c, h, w), y.reshape(b, c, h, w).to(depth.dtype), depth)
        return out, empty_record()
