r"""FPN notch filter: fixed 1-D FIR taps along the width and/or height of (B, C, H, W) depth.

Applies the filters of Georgiev, Bregovic, Gotchev, "Fixed-pattern noise suppression in
low-sensing environment of Time-of-Flight devices", IEEE SAS 2015, Sec. III (designed offline by
:mod:`tof_fpn_torch.design`; this module only needs their taps). ``dim=-1`` filters along the width
and removes *column* stripes (a pattern that changes from column to column), ``dim=-2`` removes row
stripes. Centring as ``scipy.ndimage.convolve1d``; even-length taps (odd order) put the output half a
sample off the input grid (:attr:`FPNFilter.delay`).

Invalid pixels (:func:`~tof_fpn_torch.runtime.valid_mask`) and isolated outliers (a valid pixel
more than 3 times as far, or less than a third as far, as each valid neighbour along the filtering
axis) are not used as data: the weight of the taps that fall on them goes to the output pixel
itself, and they get their input values back (invalid stays invalid, bit for bit, NaN, 0 and
other codes alike; a signalling NaN comes back quiet). A valid output moves by at most
``sum_{k != c} |h_k|`` times the largest difference to a usable depth within the filter's support;
the rule and this bound are in :mod:`.holes`. With every pixel valid and the depths within a
factor 3 (no pixel can be an outlier), the filter is the plain FIR.
"""

# no `from __future__ import annotations`: TorchScript reads the class-level attribute types below
# as objects, not strings
import math

import torch
from torch import nn
from torch.nn.utils import parametrize

from ._checks import check_image, check_taps, check_tensor_type, normalize_dims
from .fir import BORDER_MODES, fir_last, fir_operators
from .holes import certified, holed_exact, holed_lines, tap_gains
from .validity import all_valid, valid_mask, valid_range

__all__ = ["FPNFilter", "fpn_filter"]


def _tracing() -> bool:
    """True while ``torch.jit.trace``, ``torch.export`` / ONNX or ``torch.compile`` trace the call:
    then the branch-free, out-of-place path is taken (no data-dependent shortcuts)."""
    if torch.jit.is_scripting():
        return False
    return torch.jit.is_tracing() or torch.compiler.is_compiling() or torch.onnx.is_in_onnx_export()


def _along(
    x: torch.Tensor, taps: torch.Tensor, d: int, border: str, ops: list[torch.Tensor], fast: bool
) -> torch.Tensor:
    if d == -1:
        return fir_last(x, taps, border, ops, fast)
    y = fir_last(x.transpose(-1, -2).contiguous(), taps, border, ops, fast)
    return y.transpose(-1, -2).contiguous()


def _lines(t: torch.Tensor, d: int) -> torch.Tensor:
    """(B, C, H, W) -> contiguous (lines, length) along ``d``."""
    if d == -1:
        return t.contiguous().view(-1, t.shape[-1])
    return t.transpose(-1, -2).contiguous().view(-1, t.shape[-2])


def _unlines(t: torch.Tensor, shape: list[int], d: int) -> torch.Tensor:
    if d == -1:
        return t.view(shape)
    return t.view(shape[0], shape[1], shape[3], shape[2]).transpose(-1, -2).contiguous()


def _per_image(shape: list[int], d: int) -> int:
    """Lines per image of :func:`_lines` (rows for ``d = -1``, columns for ``-2``)."""
    return shape[-2] if d == -1 else shape[-1]


def _fpn_filter(
    x: torch.Tensor,
    mask: torch.Tensor | None,
    taps: torch.Tensor,
    dims: list[int],
    border: str,
    taps_ops: list[torch.Tensor],
) -> torch.Tensor:
    """The filter without argument checks (shared by :func:`fpn_filter` and :class:`FPNFilter`)."""
    if x.numel() == 0:
        return x.clone()
    out_dtype = x.dtype
    work = x.float() if x.dtype == torch.float16 or x.dtype == torch.bfloat16 else x
    tracing = _tracing()
    fast = not tracing and not (torch.is_grad_enabled() and (x.requires_grad or taps.requires_grad))
    shape = list(work.shape)
    rng: tuple[float, float] | None = None
    if not tracing and mask is None:
        rng = valid_range(work, fast)  # one min/max: the clean frame's shortcut
    valid: torch.Tensor | None = None
    if rng is None and (mask is not None or not fast):
        valid = valid_mask(work, mask=mask)  # else the chunks find the invalid pixels themselves
    gains = (0.0, 0.0) if tracing else tap_gains(taps)
    y = work
    for i, d in enumerate(dims):
        r = rng
        if r is not None and r[0] > 0:  # all valid (so no outlier: they sit by holes): plain FIR
            prev = y
            y = _along(y, taps, d, border, taps_ops, fast)
            if not certified(r[0], r[1], gains, border):  # ringing past 0 at a steep step
                y = _keep_valid(y, prev)
            if i + 1 < len(dims):
                rng = valid_range(y, fast)
            continue
        if fast:
            top = 0.0 if r is None else r[1]
            v2 = None if valid is None else _lines(valid, d)
            lines = _per_image(shape, d)
            y2 = holed_lines(
                _lines(y, d), v2, taps, border, taps_ops, gains, top, lines, r is not None
            )
        else:
            vm = valid if valid is not None else valid_mask(y)
            y2 = holed_exact(
                _lines(y, d), _lines(vm, d), taps, border, taps_ops, fast, _per_image(shape, d)
            )
        y = _unlines(y2, shape, d)
        if r is not None and i + 1 < len(dims):
            rng = valid_range(y, fast)
    return y.to(out_dtype)


def _keep_valid(y: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """A valid input pixel never comes out invalid: where the filter rang to <= 0 (next to a
    steep depth step), the input value is kept (one min / max check)."""
    if all_valid(y):
        return y
    return torch.where(valid_mask(y), y, x)


def fpn_filter(
    x: torch.Tensor,
    taps: torch.Tensor,
    dim: int | tuple[int, ...] = -1,
    border: str = "reflect",
    mask: torch.Tensor | None = None,
) -> torch.Tensor:
    r"""Apply 1-D FIR ``taps`` along ``dim`` of a (B, C, H, W) depth tensor, invalid pixels kept.

    The functional form of :class:`FPNFilter`, with the same checks and the same invalid-pixel
    handling; it builds the small fast-path matrices on every call (the module keeps them).

    Args:
        x: (B, C, H, W) floating depth; invalid pixels (NaN, +-inf, <= 0) are returned unchanged.
        taps: (L,) filter taps ``h[0..L-1]``, finite.
        dim: ``-1`` (along the width: column stripes), ``-2`` (rows) or ``(-2, -1)``.
        border: ``"reflect"`` (``dcb|abcd|cba``), ``"replicate"``, ``"circular"`` or ``"zeros"``.
        mask: optional (B, C, H, W) bool, False marks more invalid pixels.

    Returns:
        (B, C, H, W), dtype and device of ``x`` (float16 / bfloat16 computed in float32).

    Example:
        >>> y = fpn_filter(torch.full((1, 1, 4, 9), 2.0), torch.tensor([0.25, 0.5, 0.25]))
        >>> y[0, 0, 0]
        tensor([2., 2., 2., 2., 2., 2., 2., 2., 2.])
    """
    check_image(x, "x")
    taps = torch.as_tensor(taps)
    check_taps(taps)
    if border not in BORDER_MODES:
        raise ValueError(f"border must be one of {BORDER_MODES}, got {border!r}")
    dims = list(normalize_dims(dim))
    if mask is not None and mask.shape != x.shape:
        raise ValueError(f"mask must have the shape of x {list(x.shape)}, got {list(mask.shape)}")
    return _fpn_filter(x, mask, taps.to(x.device), dims, border, [])


class FPNFilter(nn.Module):
    r"""Fixed 1-D FIR notch filter along the width and/or height of (B, C, H, W) depth.

    A thin holder of buffers for :func:`fpn_filter`: the taps (float64, or a parameter when
    ``trainable``) and the fast-path matrices built from them when the taps are
    set (:meth:`set_taps`; rebuilt in eager mode when the taps change in place, e.g. by an optimiser).
    What the design was (``order``, ``rho``, ``notches``) is kept as attributes, so TorchScript
    archives carry it and :func:`tof_fpn_torch.export.export_onnx` writes it into the ONNX metadata.
    Build one from a design with :func:`tof_fpn_torch.build.filter_from_design`.

    Args:
        taps: ``h[0..L-1]`` (1-D, finite), e.g. ``design_fpn(20, 0.14).taps``.
        dim: ``-1`` filters along the width (removes column stripes), ``-2`` along the height
            (row stripes), ``(-2, -1)`` both.
        border: ``"reflect"`` (default), ``"replicate"``, ``"circular"`` or ``"zeros"``. Any width
            works, also narrower than the filter.
        trainable: make the taps an ``nn.Parameter``.
        allow_shift: accept even-length taps (odd order), whose output sits half a sample off the
            input grid (:attr:`delay` 0.5). Refused by default: the stage must never shift the
            image; compensate the delay in the design (``compensate_delay=True`` of the builders).
        order, rho, notches: the design the taps come from (metadata; ``order`` defaults to
            ``L - 1``, ``rho`` to NaN = unknown, ``notches`` to none).
        compensated: the taps include a half-sample delay compensator (metadata).

    Shape:
        - Input: (B, C, H, W) float, optional ``mask`` (B, C, H, W) bool (True = valid).
        - Output: (B, C, H, W), same dtype and device.

    Example:
        >>> f = FPNFilter(torch.tensor([0.25, 0.5, 0.25]))
        >>> f(torch.rand(2, 1, 48, 64) + 1.0).shape
        torch.Size([2, 1, 48, 64])
    """

    __jit_ignored_attributes__ = ["design"]
    # attribute types for TorchScript (an empty list would otherwise be read as List[Tensor])
    order: int
    rho: float
    notches: list[float]
    dims: list[int]
    border: str
    compensated: bool

    def __init__(
        self,
        taps,
        dim: int | tuple[int, ...] = -1,
        border: str = "reflect",
        trainable: bool = False,
        allow_shift: bool = False,
        *,
        order: int | None = None,
        rho: float | None = None,
        notches: tuple[float, ...] = (),
        compensated: bool = False,
    ) -> None:
        super().__init__()
        with torch.inference_mode(False):  # the module's own tensors, even if built in one
            t = torch.as_tensor(taps, dtype=torch.float64).detach().clone()
        check_taps(t)
        if border not in BORDER_MODES:
            raise ValueError(f"border must be one of {BORDER_MODES}, got {border!r}")
        if t.numel() % 2 == 0 and not allow_shift:
            raise ValueError(
                f"taps of even length {t.numel()} (an odd order) shift the output by half a "
                "sample; use an even order, compensate the delay (compensate_delay=True in "
                "tof_fpn_torch.build), or pass allow_shift=True to accept the shift"
            )
        self.dims = list(normalize_dims(dim))
        self.border = border
        self.order = int(t.numel() - 1 if order is None else order)
        self.rho = math.nan if rho is None else float(rho)
        self.notches = [float(w) for w in notches]
        self.compensated = bool(compensated)
        self.design = None  # the offline design object, when a builder made this module
        with torch.inference_mode(False):
            if trainable:
                self.taps = nn.Parameter(t)
            else:
                self.register_buffer("taps", t)
            self._ops_version = -1
            self._build_operators()

    @torch.jit.unused
    def _taps_version(self) -> int:
        """The version counter of the tensor the taps are trained as (the taps, or under a
        parametrisation, its ``original``): a host integer, no device sync."""
        if parametrize.is_parametrized(self, "taps"):
            return self.parametrizations["taps"].original._version
        return self.taps._version

    @torch.jit.unused
    def _build_operators(self) -> None:
        with torch.inference_mode(False):
            taps = self.taps.detach()
            for i, op in enumerate(fir_operators(taps, self.border)):
                self.register_buffer(f"_taps_op{i}", op.to(taps.device), persistent=False)
        self._ops_version = self._taps_version()

    @torch.jit.unused
    def _refresh_operators(self) -> None:
        """Rebuild the matrices when the taps changed in place (optimiser step, load_state_dict)."""
        if self._ops_version != self._taps_version():
            self._build_operators()

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        state_dict.pop(prefix + "window", None)  # the hole-fill window of earlier versions
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    @torch.jit.unused
    def set_taps(self, taps) -> None:
        """Replace the taps (same length) and rebuild the fast-path matrices."""
        t = torch.as_tensor(taps, dtype=torch.float64)
        check_taps(t)
        if t.shape != self.taps.shape:
            raise ValueError(
                f"taps must keep their length {self.taps.numel()}, got shape {list(t.shape)}"
            )
        with torch.no_grad():
            self.taps.copy_(t)
        self._build_operators()

    @property
    def delay(self) -> float:
        """Residual shift of the output in samples: output sample ``n`` estimates input position
        ``n + delay`` (0.5 for even-length taps, else 0)."""
        return 0.5 if self.taps.numel() % 2 == 0 else 0.0

    def extra_repr(self) -> str:
        return (
            f"taps={self.taps.numel()}, order={self.order}, rho={self.rho}, dim={tuple(self.dims)}, "
            f"border={self.border!r}, delay={self.delay}, compensated={self.compensated}"
        )

    def forward(self, x: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        if not torch.jit.is_scripting():
            check_tensor_type(x, "x")
            check_tensor_type(mask, "mask", optional=True)
            if torch.is_autocast_enabled(x.device.type):
                return self._full_precision(x, mask)
        return self._forward(x, mask)

    @torch.jit.unused
    def _full_precision(self, x: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        """:meth:`_forward` with autocast off (float32 work, the input's dtype out; see
        :meth:`FPNSuppression._full_precision`)."""
        with torch.autocast(x.device.type, enabled=False):
            return self._forward(x, mask)

    def _forward(self, x: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        check_image(x, "x")
        if mask is not None and mask.shape != x.shape:
            raise ValueError(
                f"mask must have the shape of x {list(x.shape)}, got {list(mask.shape)}"
            )
        if not torch.jit.is_scripting():
            self._refresh_operators()
        taps_ops = [self._taps_op0, self._taps_op1, self._taps_op2, self._taps_op3]
        return _fpn_filter(x, mask, self.taps, self.dims, self.border, taps_ops)
