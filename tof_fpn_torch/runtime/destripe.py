r"""Broadband column / row offset removal from one frame (beyond the paper; torch only).

Real ToF sensors have per-column (and per-row) read-out offsets at *all* spatial frequencies, not
only the periodic stripes at ``2 pi / 3`` and ``pi`` that the paper's notch filter removes.
:func:`destripe` estimates one offset per column (``dim=-1``; per row with ``dim=-2``; both, columns
first, with ``(-2, -1)``) from the frame itself and subtracts it from the valid pixels.

Estimator (details in :mod:`._destripe_core` and docs/destripe.md):

1. **differences** ``g = D[:, x + 1] - D[:, x]`` in every row: a column offset appears in every
   row of its column pair, a vertical scene edge in one pair only, a smooth scene as a slow trend;
2. **robust per-pair means** over the rows: a difference further than ``clip`` robust sigmas from
   a pilot (per-pair median and trimmed mean of a row subsample) is an edge, a thin bar, a curved
   object or clutter and is replaced by the pilot; a pair mean far outside the population of pair
   means is an edge most rows share and is dropped;
3. **profile**: the pair means integrated along the line, minus their local linear fit over
   ``width`` columns (at most a quarter of the line): offsets slower than that, and the scene's
   slopes, are never touched: the low-pass depth does not move;
4. **shrinkage ("never hurts")**: the top and the bottom half of the rows are estimated
   separately. A stripe is in both; noise and structure confined to one half are not. In octave
   bands of the profile, over windows of ``local_width`` columns (``shrink="local"``, default) or
   the whole line (``"global"``), the profile ``p`` of all rows is multiplied by

   ``f = clamp((<p_top, p_bottom> - z sd0) / <p, p>, 0, 1)``

   with ``sd0`` the standard deviation of ``<p_top, p_bottom>`` without stripes (from the halves'
   difference) and ``z = NULL_Z = 2.5`` (:mod:`._destripe_core`). ``<p_top, p_bottom> / <p, p>`` is the positive-part
   James-Stein (Wiener) factor with the noise energy measured by cross-validation instead of a
   standard-error formula: measured, ``sigma / sqrt(rows)`` undercounted the noise that the
   integration of trimmed means leaves and all scene leakage, and let a stripe-free 32 x 39 scene
   lose 2 dB. A stripe-free frame comes back almost unchanged, and the offsets have zero mean over
   the valid pixels, so the image mean does not move.

``domain="complex"`` (needs ``amplitude`` and ``modulation_frequency_hz``) does the same on
``z = A e^{j phi}``, ``phi = 4 pi f D / c_L`` (the two parts share the inlier test), where a
read-out offset is additive, drops the part of each column's offset along the column's mean phasor
in proportion to the column's phase coherence (a vertical amplitude texture lies there; see
:func:`._destripe_core.coherent_projection`), and converts back by the wrapped phase change:
``D' = D + c_L / (4 pi f) * angle(z' conj(z))``, re-wrapped into ``[0, c_L / 2f)`` when ``wrap``
(single-frequency depth; ``wrap=False`` keeps e.g. unwrapped multi-frequency depth as it is).

What it cannot tell from a stripe: structure that changes from column to column and is the same in
both halves of the frame (a thin vertical bar or a vertical texture over the full height; in the
complex domain also a vertical *amplitude* texture such as a painted pattern), and edges shared by
most rows that are no larger than the stripe steps.

Amplitude: in ``domain="depth"`` it only extends the validity rule (finite, ``>= 0``).
"""

# no `from __future__ import annotations`: TorchScript reads the class-level attribute types below
import math

import torch

from .. import constants as K
from ._checks import check_image, check_same_shape, normalize_dims
from ._destripe_core import column_offsets
from ._phasor import depth_from_phase_change, metres_per_radian, phasor
from .stage import RecordField, Setting, Stage, check_settings
from .validity import all_valid, valid_mask

__all__ = ["Destripe", "destripe"]

SHRINK_MODES = ("global", "local", "none")
DOMAINS = ("depth", "complex")


def _check_params(
    width: int,
    clip: float,
    shrink: str,
    domain: str,
    modulation_frequency_hz: float | None,
    local_width: int,
) -> None:
    for name, v in (("width", width), ("local_width", local_width)):
        if isinstance(v, bool) or not isinstance(v, int) or v < 3:
            raise ValueError(f"{name} must be an int >= 3 (columns), got {v!r}")
    if isinstance(clip, bool) or not isinstance(clip, (int, float)) or not 0 < clip < math.inf:
        raise ValueError(f"clip must be a finite number > 0 (robust sigmas), got {clip!r}")
    if shrink not in SHRINK_MODES:
        raise ValueError(f"shrink must be one of {SHRINK_MODES}, got {shrink!r}")
    if domain not in DOMAINS:
        raise ValueError(f"domain must be one of {DOMAINS}, got {domain!r}")
    f = modulation_frequency_hz
    if domain == "complex":
        if isinstance(f, bool) or not isinstance(f, (int, float)) or not 0 < f < math.inf:
            raise ValueError(
                f"modulation_frequency_hz must be a finite number > 0 (Hz) with domain='complex', "
                f"got {f!r}"
            )
    elif f is not None:
        raise ValueError(
            f"modulation_frequency_hz is used only with domain='complex', got {f!r} with "
            f"domain={domain!r}"
        )


def _check_inputs(depth: torch.Tensor, amplitude: torch.Tensor | None, domain: str) -> None:
    check_image(depth, "depth")
    if amplitude is not None:
        check_image(amplitude, "amplitude")
        check_same_shape(amplitude, depth, "amplitude", "depth")
    elif domain == "complex":
        raise ValueError(
            "amplitude is required with domain='complex' (z = A e^{j phi}); got None, allowed: a "
            "(B, C, H, W) tensor of the shape of depth"
        )


def _along(
    x: torch.Tensor,
    valid: torch.Tensor | None,
    d: int,
    width: int,
    clip: float,
    shrink: str,
    local_width: int,
) -> torch.Tensor:
    """Offsets (N, K, H, W)-broadcastable of (N, K, H, W) ``x`` along dim ``d`` (-1: per column)."""
    xt = x.transpose(-1, -2) if d == -2 else x
    vt = None if valid is None or d == -1 else valid.transpose(-1, -2)
    if d == -1:
        vt = valid
    off, _ = column_offsets(xt, vt, width, clip, shrink, local_width, K.DESTRIPE_PILOT_ROWS)
    return off[..., :, None] if d == -2 else off[..., None, :]


def _usable(x: torch.Tensor) -> bool:
    """At least 2 lines to cross-validate over and 2 samples along the offset axis."""
    return x.shape[-2] >= 2 and x.shape[-1] >= 2


def _destripe(
    depth: torch.Tensor,
    amplitude: torch.Tensor | None,
    dims: list[int],
    width: int,
    clip: float,
    shrink: str,
    local_width: int,
    domain: str,
    modulation_frequency_hz: float,
    wrap: bool,
) -> torch.Tensor:
    """:func:`destripe` without argument checks (shared with :class:`Destripe`)."""
    if depth.numel() == 0:
        return depth.clone()
    out_dtype = depth.dtype
    half = depth.dtype == torch.float16 or depth.dtype == torch.bfloat16
    work = depth.float() if half else depth
    b, c, h, w = work.shape
    valid: torch.Tensor | None = None
    amp_ok = True
    if amplitude is not None:  # one min/max instead of a mask when all amplitudes are usable
        lo, hi = torch.aminmax(amplitude)
        amp_ok = bool(lo >= 0) and bool(hi < math.inf)
    if not amp_ok or not all_valid(work):
        valid = valid_mask(work, amplitude).reshape(b * c, 1, h, w)
    if domain == "depth":
        x = work.reshape(b * c, 1, h, w)
        y = x
        for d in dims[::-1]:  # columns first
            if _usable(x):
                y = y - _along(y, valid, d, width, clip, shrink, local_width)
        return _keep(y, x, valid).reshape(b, c, h, w).to(out_dtype)
    assert amplitude is not None
    amp = amplitude.to(work.dtype).reshape(b * c, 1, h, w)
    x = work.reshape(b * c, 1, h, w)
    scale = metres_per_radian(modulation_frequency_hz)
    if valid is not None:
        x0 = torch.where(valid, x, torch.zeros_like(x))
        amp = torch.where(valid, amp, torch.zeros_like(amp))
    else:
        x0 = x
    z = phasor(x0, amp, scale)
    zc = z
    for d in dims[::-1]:
        if _usable(z):
            zc = zc - _along(zc, valid, d, width, clip, shrink, local_width)
    y = depth_from_phase_change(x, z, zc, scale, wrap)
    return _keep(y, x, valid).reshape(b, c, h, w).to(out_dtype)


def _keep(y: torch.Tensor, x: torch.Tensor, valid: torch.Tensor | None) -> torch.Tensor:
    """``y`` at the valid pixels of ``x`` whose output is valid too; ``x`` elsewhere: invalid
    pixels come out bit-identical, and a valid pixel never comes out invalid (a correction that
    would push a depth to <= 0 keeps the input there)."""
    if valid is None:
        if all_valid(y):  # the usual case: one min/max over the output
            return y
        return torch.where(valid_mask(y), y, x)
    return torch.where(valid & valid_mask(y), y, x)


def destripe(
    depth: torch.Tensor,
    amplitude: torch.Tensor | None = None,
    dim: int | tuple[int, ...] = -1,
    width: int = K.DESTRIPE_WIDTH,
    clip: float = K.DESTRIPE_CLIP,
    shrink: str = "local",
    domain: str = "depth",
    modulation_frequency_hz: float | None = None,
    wrap: bool = True,
    local_width: int = K.DESTRIPE_LOCAL_WIDTH,
) -> torch.Tensor:
    r"""Remove broadband column (``dim=-1``) and/or row (``dim=-2``) offsets from each frame.

    The estimator and the shrinkage rule are described in the module docstring; in short: robust
    (``clip``-sigma trimmed) means of the differences between neighbouring columns, integrated and
    high-passed over ``width`` columns, scaled per octave band and window by
    ``f = clamp((<p_top, p_bottom> - z sd0) / <p, p>, 0, 1)`` where ``p_top``, ``p_bottom`` are the
    profiles of the top and the bottom half of the rows and ``p`` that of all rows.

    Args:
        depth: (B, C, H, W) floating depth. Invalid pixels (NaN, +-inf, <= 0) are never used and
            are returned bit-identical.
        amplitude: optional (B, C, H, W) amplitude: a NaN, inf or negative amplitude also marks
            the pixel invalid. Required with ``domain="complex"``.
        dim: ``-1`` column offsets (vertical stripes), ``-2`` row offsets, ``(-2, -1)`` both.
        width: high-pass width in columns (int >= 3): offsets varying more slowly are kept.
        clip: trimming threshold in robust sigmas (> 0).
        shrink: ``"local"`` (default: per window of ``local_width`` columns), ``"global"`` or
            ``"none"``.
        domain: ``"depth"`` (offsets in depth units) or ``"complex"`` (offsets in
            ``z = A e^{j 4 pi f D / c_L}``, see the module docstring).
        modulation_frequency_hz: ``f`` for ``domain="complex"`` (finite > 0), else None.
        wrap: complex domain only: re-wrap the output into ``[0, c_L / 2f)``.
        local_width: window of ``shrink="local"`` (int >= 3).

    Returns:
        (B, C, H, W), dtype and device of ``depth`` (float16 / bfloat16 computed in float32).

    Raises:
        ValueError: an argument outside what is allowed (the message names it, the value and the
            allowed values).

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> stripes = 0.01 * torch.randn(1, 1, 1, 256, generator=g)
        >>> noisy = 2.0 + stripes + 0.002 * torch.randn(1, 1, 64, 256, generator=g)
        >>> removed = (noisy - destripe(noisy)).mean(2)  # the offset taken from each column
        >>> r = torch.corrcoef(torch.cat([removed, stripes[0]]).reshape(2, -1))[0, 1]
        >>> bool(r > 0.95)  # all but the slowest part (under 1 / 31 cycles per column)
        True
    """
    _check_inputs(depth, amplitude, domain)
    dims = list(normalize_dims(dim))
    _check_params(width, clip, shrink, domain, modulation_frequency_hz, local_width)
    f = 1.0 if modulation_frequency_hz is None else float(modulation_frequency_hz)
    return _destripe(
        depth, amplitude, dims, width, float(clip), shrink, local_width, domain, f, bool(wrap)
    )


class Destripe(Stage):
    r"""Broadband column / row offset removal, the module form of :func:`destripe`.

    Holds the settings (no learned or fixed coefficients: the offsets are estimated from each
    frame); TorchScript-scriptable, device and dtype follow the input. The call signature
    ``(depth, amplitude=None) -> depth`` is the one :class:`FPNSuppression` composes.

    Args:
        dim, width, clip, shrink, domain, modulation_frequency_hz, wrap, local_width: see
            :func:`destripe`.

    Shape:
        - depth: (B, C, H, W) float; amplitude: optional, same shape.
        - Output: (B, C, H, W), invalid pixels unchanged.

    Example:
        >>> m = Destripe(dim=(-2, -1))
        >>> m(torch.rand(2, 1, 40, 56) + 1.0).shape
        torch.Size([2, 1, 40, 56])
    """

    settings = (
        Setting("width", int, K.DESTRIPE_WIDTH, "columns of the local linear fit kept", low=3),
        Setting(
            "clip",
            float,
            K.DESTRIPE_CLIP,
            "robust sigmas beyond which a step is an edge",
            low=0.0,
            open_low=True,
        ),
        Setting(
            "shrink", str, "local", "the never-hurts shrinkage's windows", choices=SHRINK_MODES
        ),
        Setting("domain", str, "depth", "offsets of the depth or of A e^{j phi}", choices=DOMAINS),
        Setting(
            "modulation_frequency_hz",
            float,
            None,
            "Hz, with domain='complex'",
            low=0.0,
            open_low=True,
        ),
        Setting("wrap", bool, True, "re-wrap the complex-domain depth into one range"),
        Setting("local_width", int, K.DESTRIPE_LOCAL_WIDTH, "columns per shrinkage window", low=3),
    )
    record = (RecordField("moved", "valid pixels whose depth changed"),)

    dims: list[int]
    width: int
    clip: float
    shrink: str
    domain: str
    modulation_frequency_hz: float
    wrap: bool
    local_width: int

    def __init__(
        self,
        dim: int | tuple[int, ...] = -1,
        width: int = K.DESTRIPE_WIDTH,
        clip: float = K.DESTRIPE_CLIP,
        shrink: str = "local",
        domain: str = "depth",
        modulation_frequency_hz: float | None = None,
        wrap: bool = True,
        local_width: int = K.DESTRIPE_LOCAL_WIDTH,
    ) -> None:
        super().__init__()
        _check_params(width, clip, shrink, domain, modulation_frequency_hz, local_width)
        check_settings(type(self), width=width, clip=clip, shrink=shrink, wrap=wrap)
        self.dims = list(normalize_dims(dim))
        self.width = int(width)
        self.clip = float(clip)
        self.shrink = shrink
        self.domain = domain
        f = modulation_frequency_hz
        self.modulation_frequency_hz = 1.0 if f is None else float(f)
        self.wrap = bool(wrap)
        self.local_width = int(local_width)

    def extra_repr(self) -> str:
        s = (
            f"dim={tuple(self.dims)}, width={self.width}, clip={self.clip}, "
            f"shrink={self.shrink!r}, domain={self.domain!r}"
        )
        if self.domain == "complex":
            s += f", modulation_frequency_hz={self.modulation_frequency_hz:g}, wrap={self.wrap}"
        return s

    def _run(
        self, depth: torch.Tensor, amplitude: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        check_image(depth, "depth")
        if amplitude is not None:
            check_image(amplitude, "amplitude")
            check_same_shape(amplitude, depth, "amplitude", "depth")
        elif self.domain == "complex":
            raise ValueError(
                "amplitude is required with domain='complex' (z = A e^{j phi}); got None"
            )
        y = _destripe(
            depth,
            amplitude,
            self.dims,
            self.width,
            self.clip,
            self.shrink,
            self.local_width,
            self.domain,
            self.modulation_frequency_hz,
            self.wrap,
        )
        moved = (y != depth) & (y == y)  # NaN-safe: an invalid pixel is never moved
        return y, {"moved": moved.flatten(1).sum(1).to(torch.float32)}
