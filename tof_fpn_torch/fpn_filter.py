r"""Run-time FIR stage: fixed 1-D notch taps along the width and/or height of (B, C, H, W) tensors.

Applies the filters of :mod:`tof_fpn_torch.design` (Georgiev, Bregovic, Gotchev, "Fixed-pattern noise
suppression in low-sensing environment of Time-of-Flight devices", IEEE SAS 2015, Sec. III) to depth
maps. ``dim=-1`` filters along the width and removes *column* stripes (a pattern that changes from
column to column), ``dim=-2`` removes row stripes.

Convention: ``y[n] = sum_k h[k] x[n + L // 2 - k]`` for ``L`` taps, i.e. the same as
``scipy.ndimage.convolve1d(x, h, mode=...)``. For odd ``L`` (even order) the output is centred on
the input; for even ``L`` (odd order, type II) it sits half a sample later (``delay == 0.5``), unless
``compensate_delay=True`` folds a half-sample interpolator into the taps (see :func:`half_sample_taps`).

Speed: a direct convolution costs ``L`` multiply-adds per sample and ``F.conv1d`` does not reach
BLAS speed for one long single-channel kernel. The rows are consecutive in memory, so the flattened
batch is one long signal. For float32 on CPU (inference) that signal, viewed as (n / P, P), is a
channels-last image whose ``P = 16`` channels are its polyphase components; the FIR is then one
16-in, 16-out convolution with ``K = ceil((L - 1) / P) + 1`` taps (``P K = 64`` multiply-adds per
sample for ``L = 42``) that oneDNN runs at GEMM speed, read straight from the input and written
straight into the output (no copies). For other dtypes/devices the signal is cut into blocks of
``M >= L - 1`` samples and each block of output is one row of two small GEMMs with banded
Toeplitz matrices, ``Z_j = X_j T_0 + X_{j+1}[:, :L-1] T_1`` (``M + L - 1`` multiply-adds per
sample). Either way only the ``L - 1`` border columns of each row, the ones whose window crosses a
row end, are then redone: the padding is folded into small matrices and (except for circular)
all row seams are one more GEMM from a strided view of the input into a strided view of the
output. Extra memory: the
output. With autograd, or when exporting, a mathematically identical out-of-place version (pad,
reshape, two matmuls) is used. See docs/runtime.md for the measured speed.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from ._checks import check_image, check_taps, normalize_dims
from .design import DEFAULT_NOTCHES, design_fpn

__all__ = ["BORDER_MODES", "FPNFilter", "fpn_filter", "half_sample_taps", "pad_index"]

BORDER_MODES: tuple[str, ...] = ("reflect", "replicate", "circular", "zeros")


def half_sample_taps(length: int = 32, band_edge: float = 0.9 * math.pi) -> np.ndarray:
    """Symmetric even-length FIR approximating a half-sample delay on ``[0, band_edge]`` (offline).

    Least-squares fit of the zero-phase response ``2 sum_k d_k cos(w (k + 1/2)) = 1``. Any
    even-length symmetric filter has a zero at ``pi``, so the fit can only hold below ``pi``;
    measured maximum errors (length 32): 5e-5 up to ``0.8 pi``, 3e-3 up to ``0.88 pi``,
    9e-3 up to ``0.9 pi``. Convolved with type-II taps it gives odd-length taps with an integer
    delay.
    """
    if isinstance(length, bool) or not isinstance(length, int) or length < 2 or length % 2:
        raise ValueError(f"length must be an even int >= 2, got {length!r}")
    if not (0.0 < float(band_edge) < math.pi):
        raise ValueError(f"band_edge must lie in (0, pi), got {band_edge!r}")
    k = np.arange(length // 2) + 0.5
    w = np.linspace(0.0, float(band_edge), 64 * length)
    half, *_ = np.linalg.lstsq(2.0 * np.cos(np.outer(w, k)), np.ones_like(w), rcond=None)
    return np.concatenate([half[::-1], half])


def pad_index(
    n: int, left: int, right: int, mode: str, device: torch.device
) -> tuple[torch.Tensor, torch.Tensor]:
    """Source indices and weights for padding a length-``n`` axis by ``left``/``right`` samples.

    Works for any ``n >= 1`` (also when the padding is longer than the axis). ``reflect`` is
    ``dcb|abcd|cba`` (torch ``reflect``, OpenCV ``BORDER_REFLECT_101``, SciPy ``mirror``);
    ``zeros`` gives weight 0 outside.
    """
    i = torch.arange(-left, n + right, device=device)
    weight = torch.ones(i.shape, device=device)
    if mode == "reflect":
        if n == 1:
            idx = torch.zeros_like(i)
        else:
            period = torch.full_like(i, 2 * (n - 1))  # tensor modulus: exports with symbolic n
            j = torch.remainder(i, period)
            idx = torch.where(j >= n, period - j, j)
    elif mode == "replicate":
        idx = torch.clamp(i, 0, n - 1)
    elif mode == "circular":
        idx = torch.remainder(i, torch.full_like(i, n))
    elif mode == "zeros":
        weight = ((i >= 0) & (i < n)).to(weight.dtype)
        idx = torch.clamp(i, 0, n - 1)
    else:
        raise ValueError("border mode must be reflect, replicate, circular or zeros, got " + mode)
    return idx, weight


def _pad_last(x: torch.Tensor, left: int, right: int, mode: str) -> torch.Tensor:
    idx, weight = pad_index(x.shape[-1], left, right, mode, x.device)
    out = x.index_select(-1, idx)
    if mode == "zeros":
        out = out * weight.to(x.dtype)
    return out


def _toeplitz(g: torch.Tensor, block: int) -> tuple[torch.Tensor, torch.Tensor]:
    """``T[m, i] = g[m - i]`` (0 <= m - i < L), split into ``T0 = T[:M]`` and ``T1 = T[M:]``."""
    length = g.shape[0]
    m = torch.arange(block + length - 1, device=g.device).unsqueeze(1)
    i = torch.arange(block, device=g.device).unsqueeze(0)
    k = m - i
    inside = (k >= 0) & (k < length)
    gz = torch.cat([g, torch.zeros(1, dtype=g.dtype, device=g.device)])
    t = gz[torch.where(inside, k, torch.full_like(k, length))]
    return t[:block], t[block:]


def _block_size(length: int) -> int:
    return max(32, ((length - 1 + 15) // 16) * 16)


def _border_matrix(g: torch.Tensor, left: int, right: int) -> torch.Tensor:
    """Block-diagonal ``[[T(left), 0], [0, T(right)]]`` of full Toeplitz blocks."""
    p = g.shape[0] - 1
    out = torch.zeros(left + right + 2 * p, left + right, dtype=g.dtype, device=g.device)
    if left > 0:
        t0, t1 = _toeplitz(g, left)
        out[: left + p, :left] = torch.cat([t0, t1])
    if right > 0:
        t0, t1 = _toeplitz(g, right)
        out[left + p :, left:] = torch.cat([t0, t1])
    return out


def _border_operator(
    g: torch.Tensor, left: int, right: int, w: int, mode: str, k: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """Matrices mapping the first and last ``k`` columns of a row to its ``left`` + ``right``
    border outputs, padding folded in (``k == w``: one matrix for the whole row, second empty)."""
    p = g.shape[0] - 1
    idx, weight = pad_index(w, left, right, mode, g.device)
    idx = torch.cat([idx[: left + p], idx[w - right :]])  # source column of each padded sample
    weight = torch.cat([weight[: left + p], weight[w - right :]]).to(g.dtype)
    rows = _border_matrix(g, left, right) * weight.unsqueeze(1)
    if k >= w:
        a = torch.zeros(w, left + right, dtype=g.dtype, device=g.device).index_add_(0, idx, rows)
        return a, a[:0]
    src = torch.where(idx < k, idx, idx - (w - 2 * k))  # columns of [first k | last k]
    a = torch.zeros(2 * k, left + right, dtype=g.dtype, device=g.device).index_add_(0, src, rows)
    return a[:k], a[k:]


def _fir_blocked(
    x2: torch.Tensor, g: torch.Tensor, left: int, right: int, mode: str
) -> torch.Tensor:
    """Out-of-place block-Toeplitz FIR along the last axis of (R, W); differentiable, exportable."""
    length = g.shape[0]
    p = length - 1
    block = _block_size(length)
    t0, t1 = _toeplitz(g, block)
    r, w = x2.shape[0], x2.shape[1]
    nb = (w + block - 1) // block
    q = (nb + 1) * block
    xp = _pad_last(x2, left, right, mode)
    xp = torch.cat([xp, xp.new_zeros(r, q - (w + p))], 1)  # cat, not F.pad: exports to opset 17
    xb = xp.reshape(r * (nb + 1), block)
    y = xb[:-1].matmul(t0) + xb[1:, :p].matmul(t1)
    return torch.cat([y, y.new_zeros(1, block)]).reshape(r, q)[:, :w]


def _fir_inplace(
    x2: torch.Tensor, g: torch.Tensor, left: int, right: int, mode: str
) -> torch.Tensor:
    """In-place-output block-Toeplitz FIR along the last axis of a contiguous (R, W), no autograd.

    Needs ``W >= L`` and ``R * W >= L - 1 + M``.
    """
    length = g.shape[0]
    p = length - 1
    block = _block_size(length)
    t0, t1 = _toeplitz(g, block)
    r, w = x2.shape[0], x2.shape[1]
    n = r * w
    xf = x2.reshape(-1)
    out = torch.empty_like(xf)
    nbk = (n - p) // block
    xa = xf[: nbk * block].view(nbk, block)
    xb = xf.as_strided([nbk, p], [block, 1], xf.storage_offset() + block)
    z = out[left : left + nbk * block].view(nbk, block)
    # One call each: splitting into cache-sized chunks is ~10 % faster on an idle machine, but
    # every call is an OpenMP fork/join, and those stall badly when other processes hold the cores.
    torch.mm(xa, t0, out=z)
    z.addmm_(xb, t1)
    if nbk * block < n - p:  # tail: one more block, overlapping the last full one
        s0 = n - p - block
        zt = xf[s0 : s0 + block].matmul(t0) + xf[s0 + block : s0 + block + p].matmul(t1)
        out[left + s0 : left + s0 + block] = zt
    out2 = out.view(r, w)
    _redo_borders(x2, out2, g, left, right, mode)
    return out2


def _redo_borders(
    x2: torch.Tensor, out2: torch.Tensor, g: torch.Tensor, left: int, right: int, mode: str
) -> None:
    """Overwrite the ``left`` + ``right`` border columns of contiguous ``out2`` (R, W) from
    contiguous ``x2``: their windows cross a row end.

    The padding is a linear map of the row's end columns, so it is folded into small matrices.
    Except for ``circular``, the left outputs depend on the first ``k`` columns only and the right
    outputs on the last ``k`` (``k = L - 1``; ``L`` for ``L = 2``, whose reflected right neighbour
    lies one column further in). The end of row ``i`` and the start of row ``i + 1`` are one
    contiguous run of ``2 k`` samples, and their outputs (right border of ``i``, left border of
    ``i + 1``) one contiguous run of ``L - 1``: all seams are one GEMM from a strided view of the
    input straight into a strided view of the output (no gather, no copy, one parallel region),
    plus the two outer ends.
    """
    p = g.shape[0] - 1
    r, w = x2.shape[0], x2.shape[1]
    if mode != "circular":
        if torch.jit.is_scripting():
            ops = _seam_operators(g, left, right, mode)
        else:
            ops = _cached_operators("seam", g, left, right, mode)
        seam, a_left, a_right = ops[0], ops[1], ops[2]
        k = a_left.shape[0]
        if r > 1:
            xs = x2.reshape(-1)[w - k : (r - 1) * w + k].unfold(0, 2 * k, w)
            ys = out2.reshape(-1)[w - right : (r - 1) * w + left].unfold(0, p, w)
            torch.mm(xs, seam, out=ys)
        out2[0, :left] = x2[0, :k].matmul(a_left)
        out2[r - 1, w - right :] = x2[r - 1, w - k :].matmul(a_right)
        return
    if w >= 2 * p:
        a1, a2 = _border_operator(g, left, right, w, mode, p)
        res = x2[:, :p].matmul(a1)
        res.addmm_(x2[:, w - p :], a2)
    else:
        res = x2.matmul(_border_operator(g, left, right, w, mode, w)[0])
    out2[:, :left] = res[:, :left]
    out2[:, w - right :] = res[:, left:]


def _seam_operators(g: torch.Tensor, left: int, right: int, mode: str) -> list[torch.Tensor]:
    """``[seam, A_left, A_right]`` of :func:`_redo_borders` (not ``circular``): ``A_left`` maps the
    first ``k`` columns of a row to its left border outputs, ``A_right`` the last ``k`` to the
    right ones, ``seam = [[A_right, 0], [0, A_left]]`` the end of one row and the start of the
    next to their ``L - 1`` outputs. ``k = L - 1``, or ``L`` for ``L = 2`` (whose reflected right
    neighbour lies one column further in). Independent of the row width ``W >= L``."""
    p = g.shape[0] - 1
    k = max(p, right + 1)
    a1, a2 = _border_operator(g, left, right, 2 * k, mode, k)
    a_left, a_right = a1[:, :left], a2[:, left:]
    seam = torch.zeros(2 * k, p, dtype=g.dtype, device=g.device)
    seam[:k, :right] = a_right
    seam[k:, right:] = a_left
    return [seam, a_left, a_right]


_OPERATORS: dict[tuple, list[torch.Tensor]] = {}


@torch.jit.unused
def _cached_operators(
    kind: str, g: torch.Tensor, left: int, right: int, mode: str
) -> list[torch.Tensor]:
    """Eager-mode cache of the small matrices (building them is ~50 tiny ops, ~0.3 ms per call).
    Keyed by the taps' values, so in-place changes to the taps are seen."""
    key = (kind, tuple(g.tolist()), g.dtype, g.device, left, right, mode, _phases(g.shape[0]))
    ops = _OPERATORS.get(key)
    if ops is None:
        with torch.inference_mode(False):
            g = g.clone()
            if kind == "seam":
                ops = _seam_operators(g, left, right, mode)
            else:
                ops = [_polyphase_weight(g, _phases(g.shape[0]))]
        if len(_OPERATORS) >= 64:
            _OPERATORS.clear()
        _OPERATORS[key] = ops
    return ops


def _phases(length: int) -> int:
    """Number of polyphase channels of :func:`_fir_polyphase` for ``length`` taps."""
    return 16


def _polyphase_weight(g: torch.Tensor, phases: int) -> torch.Tensor:
    """``W[q, p, 0, j] = g[j P + p - q]`` (0 outside), channels-last (P, P, 1, K) conv weight."""
    length = g.shape[0]
    k_len = (phases - 1 + length - 1) // phases + 1
    q = torch.arange(phases, device=g.device).view(phases, 1, 1)
    p = torch.arange(phases, device=g.device).view(1, phases, 1)
    j = torch.arange(k_len, device=g.device).view(1, 1, k_len)
    k = j * phases + p - q
    inside = (k >= 0) & (k < length)
    gz = torch.cat([g, torch.zeros(1, dtype=g.dtype, device=g.device)])
    wt = gz[torch.where(inside, k, torch.full_like(k, length))]
    return wt.unsqueeze(2).contiguous(memory_format=torch.channels_last)


def _fir_polyphase(
    x2: torch.Tensor, g: torch.Tensor, left: int, right: int, mode: str
) -> torch.Tensor:
    """Polyphase FIR along the last axis of a contiguous (R, W) as one multi-channel convolution.

    The rows are consecutive in memory, so the flattened batch is one long signal ``x``; viewed as
    (n / P, P) it *is* a channels-last (1, P, 1, n / P) image whose channel ``p`` holds the phase
    ``x[m P + p]``, no copy. Output phase ``q`` is ``sum_{p, j} g[j P + p - q] x[(m + j) P + p]``,
    a ``P``-in, ``P``-out convolution with ``K = ceil((L - 1) / P) + 1`` taps (``P K`` multiply-adds
    per sample), which oneDNN runs at GEMM speed; its channels-last output is again the flat
    signal. Zero conv padding of ``K`` phases on both sides lets the result be a view of the
    conv output shifted by ``left``. Only row-border columns (windows crossing a row end) and the
    last ``n mod P`` samples are then redone. Needs ``W >= L`` and ``R W >= 2 P``; no autograd.
    """
    length = g.shape[0]
    phases = _phases(length)
    k_len = (phases - 1 + length - 1) // phases + 1
    r, w = x2.shape[0], x2.shape[1]
    n = r * w
    m = n // phases
    xf = x2.reshape(-1)
    xi = xf[: m * phases].view(1, 1, m, phases).permute(0, 3, 1, 2)
    xi = xi.contiguous(memory_format=torch.channels_last)  # already is: no copy
    if torch.jit.is_scripting():
        weight = _polyphase_weight(g, phases)
    else:
        weight = _cached_operators("polyphase", g, left, right, mode)[0]
    y = F.conv2d(xi, weight, padding=(0, k_len))
    # y[.., t] (flat) = sum_k g[k] x[t - K P + k], i.e. output sample s sits at t = s + K P - left
    flat = y.permute(0, 2, 3, 1).reshape(-1)  # channels-last output: a view
    start = k_len * phases - left
    out = flat[start : start + n]
    s0 = max(m * phases - right, left)  # from here on windows reach the n mod P samples left out
    if s0 < n - right:
        out[s0 : n - right] = xf[s0 - left :].unfold(0, length, 1).matmul(g)
    out2 = out.view(r, w)
    _redo_borders(x2, out2, g, left, right, mode)
    return out2


def _fir_last(x: torch.Tensor, taps: torch.Tensor, mode: str, fast: bool) -> torch.Tensor:
    """Convolve ``x`` (..., W) with ``taps`` along the last axis, scipy ``convolve1d`` centring."""
    length = taps.shape[0]
    shape = x.shape
    w = shape[-1]
    g = taps.flip(0).to(device=x.device, dtype=x.dtype)
    if length == 1:
        return x * g[0]
    right = length // 2
    left = length - 1 - right
    x2 = x.reshape(-1, w)
    n = x2.shape[0] * w
    if (
        fast
        and w >= length
        and x.dtype == torch.float32
        and x.device.type == "cpu"
        and n >= 2 * _phases(length)
    ):
        y = _fir_polyphase(x2.contiguous(), g, left, right, mode)
    elif fast and w >= length and n >= length - 1 + _block_size(length):
        y = _fir_inplace(x2.contiguous(), g, left, right, mode)
    else:
        y = _fir_blocked(x2, g, left, right, mode)
    return y.reshape(shape)


def fpn_filter(
    x: torch.Tensor,
    taps: torch.Tensor,
    dims: list[int],
    border: str = "reflect",
    fast: bool = True,
) -> torch.Tensor:
    """Apply 1-D ``taps`` along each of ``dims`` (from {-2, -1}) of a (B, C, H, W) tensor.

    No invalid-pixel handling (see :class:`FPNFilter`). 16-bit inputs are computed in float32 and
    cast back. ``fast`` allows the in-place inference path; it is ignored when autograd is needed.
    """
    out_dtype = x.dtype
    if x.dtype == torch.float16 or x.dtype == torch.bfloat16:
        x = x.float()
    if fast and torch.is_grad_enabled() and (x.requires_grad or taps.requires_grad):
        fast = False
    y = x
    for d in dims:
        if d == -1:
            y = _fir_last(y, taps, border, fast)
        else:
            y = _fir_last(y.transpose(-1, -2).contiguous(), taps, border, fast)
            y = y.transpose(-1, -2).contiguous()
    return y.to(out_dtype)


class FPNFilter(nn.Module):
    r"""Fixed 1-D FIR notch filter along the width and/or height of a (B, C, H, W) tensor.

    Args:
        taps: ``h[0..N]`` (1-D, finite), e.g. :func:`tof_fpn_torch.design_fpn_filter` output.
        dim: ``-1`` filters along the width (removes column stripes), ``-2`` along the height
            (row stripes), ``(-2, -1)`` both.
        border: ``"reflect"`` (default, ``dcb|abcd|cba``), ``"replicate"``, ``"circular"`` or
            ``"zeros"``. Any width works, also narrower than the filter.
        compensate_delay: for even-length taps (odd order), convolve the taps with
            :func:`half_sample_taps` so that the output is aligned with the input (``delay == 0``);
            costs ``compensation_length`` taps and an error up to ~3e-3 at ``0.88 pi``.
        compensation_length, compensation_band: length and band edge of that interpolator.
        zero_is_invalid: treat exact zeros as invalid (ToF convention) besides NaN/inf.
        trainable: make the taps an ``nn.Parameter`` (initialised from ``taps``).

    Invalid pixels (NaN/inf, zeros if ``zero_is_invalid``, or ``mask == False``) are first filled
    along the filtering axis by normalized convolution with a triangular window of half-width
    ``L // 2 + 1`` (``sum w v x / sum w v`` over valid ``v``; the line mean where a gap is wider), the filter
    runs on the filled image, and the invalid pixels are written back unchanged (NaN stays NaN,
    0 stays 0). So no invalid value reaches a valid output, and nothing is smeared.

    Shape:
        - Input: (B, C, H, W) float, optional ``mask`` (B, C, H, W) bool (True = valid).
        - Output: (B, C, H, W), same dtype and device.

    Example:
        >>> f = FPNFilter.from_design(20, 0.14)
        >>> f(torch.rand(2, 1, 48, 64) + 1.0).shape
        torch.Size([2, 1, 48, 64])
    """

    __jit_ignored_attributes__ = ["design"]

    def __init__(
        self,
        taps,
        dim=-1,
        border: str = "reflect",
        compensate_delay: bool = False,
        compensation_length: int = 32,
        compensation_band: float = 0.88 * math.pi,
        zero_is_invalid: bool = True,
        trainable: bool = False,
    ) -> None:
        super().__init__()
        t = torch.as_tensor(
            np.asarray(taps, dtype=np.float64) if not torch.is_tensor(taps) else taps
        )
        if not t.is_floating_point():
            t = t.to(torch.float64)
        check_taps(t)
        if border not in BORDER_MODES:
            raise ValueError(f"border must be one of {BORDER_MODES}, got {border!r}")
        self.dims: list[int] = list(normalize_dims(dim))
        self.border = border
        self.zero_is_invalid = bool(zero_is_invalid)
        self.taps_half_sample = t.numel() % 2 == 0
        self.compensated = bool(compensate_delay) and self.taps_half_sample
        if self.compensated:
            d = half_sample_taps(compensation_length, compensation_band)
            t = torch.from_numpy(np.convolve(t.detach().double().cpu().numpy(), d))
        t = t.to(torch.float64)  # cast to the input's dtype per call; float64 keeps the design
        #: set by :mod:`tof_fpn_torch.export`: take the branch-free, exportable path
        self.export_mode = False
        self.design = None  # the FPNDesign when built by from_design
        if trainable:
            self.taps = nn.Parameter(t)
        else:
            self.register_buffer("taps", t)
        half = self.taps.numel() // 2
        window = 1.0 - torch.arange(-half - 1, half + 2).abs() / (half + 2.0)
        self.register_buffer("fill_window", window)
        self.fill_threshold = 0.5 / (half + 2.0)  # half the smallest window weight

    @classmethod
    def from_design(
        cls,
        order: int,
        rho: float,
        notches: Sequence[float] = DEFAULT_NOTCHES,
        dim=-1,
        band_weights: Sequence[float] | None = None,
        **kwargs,
    ) -> FPNFilter:
        """Design the taps with :func:`tof_fpn_torch.design_fpn` and build the filter.

        ``kwargs`` go to the constructor; the design is kept in :attr:`design`. With
        ``compensate_delay=True`` the interpolator band defaults to the top passband edge.
        """
        design = design_fpn(order, rho, notches=notches, band_weights=band_weights)
        if kwargs.get("compensate_delay", False) and "compensation_band" not in kwargs:
            kwargs["compensation_band"] = float(min(design.bands[-1, 1], 0.95 * math.pi))
        module = cls(design.taps, dim=dim, **kwargs)
        module.design = design
        return module

    @property
    def group_delay(self) -> float:
        """``(L - 1) / 2`` samples of the applied taps."""
        return (self.taps.numel() - 1) / 2.0

    @property
    def half_sample_delay(self) -> bool:
        """True when the given taps have even length (odd order): half a sample off-grid."""
        return self.taps_half_sample

    @property
    def delay(self) -> float:
        """Residual shift of the output: output sample ``n`` estimates input position ``n + delay``
        (0.5 for uncompensated even-length taps, else 0)."""
        return 0.5 if self.taps.numel() % 2 == 0 else 0.0

    def extra_repr(self) -> str:
        return (
            f"taps={self.taps.numel()}, dim={tuple(self.dims)}, border={self.border!r}, "
            f"delay={self.delay}, compensated={self.compensated}"
        )

    def valid_mask(self, x: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        """Boolean (B, C, H, W): finite, non-zero (if ``zero_is_invalid``) and ``mask``."""
        valid = torch.isfinite(x)
        if self.zero_is_invalid:
            valid = valid & (x != 0)
        if mask is not None:
            valid = valid & mask.to(torch.bool)
        return valid

    def _fill_invalid(self, x: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
        v = valid.to(x.dtype)
        x0 = torch.where(valid, x, torch.zeros_like(x))
        win = self.fill_window.to(device=x.device, dtype=x.dtype)
        d = self.dims[-1]
        num = fpn_filter(x0, win, [d], "zeros", not self.export_mode)
        den = fpn_filter(v, win, [d], "zeros", not self.export_mode)
        thr = self.fill_threshold
        local = num / torch.where(den > thr, den, torch.ones_like(den))
        line = x0.sum(d, keepdim=True) / v.sum(d, keepdim=True).clamp_min(1.0)
        image = x0.sum((-2, -1), keepdim=True) / v.sum((-2, -1), keepdim=True).clamp_min(1.0)
        line_ok = v.sum(d, keepdim=True) > 0
        fallback = torch.where(line_ok, line.expand_as(x), image.expand_as(x))
        filled = torch.where(den > thr, local, fallback)
        return torch.where(valid, x, filled)

    def forward(self, x: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        check_image(x, "x")
        if mask is not None and mask.shape != x.shape:
            raise ValueError(
                f"mask must have the shape of x {list(x.shape)}, got {list(mask.shape)}"
            )
        if not self.export_mode and mask is None and x.numel() > 0:
            # one pass, no allocation: min > 0 and max < inf (NaN fails both) means all valid
            if x.dtype == torch.float32 and not torch.jit.is_scripting():
                # same test on the bit patterns, an integer reduction (no NaN logic, faster):
                # positive finite float32 <=> 0 < bits < 0x7F800000 (+inf); sign bit -> negative.
                # (TorchScript reads view(int) as a shape, so it keeps the float test.)
                lo, hi = torch.aminmax(x.view(torch.int32))
                all_valid = bool(lo > 0) and bool(hi < 0x7F800000)
            else:
                lo, hi = torch.aminmax(x)
                all_valid = bool(lo > 0) and bool(hi < math.inf)
            if all_valid:
                return fpn_filter(x, self.taps, self.dims, self.border, True)
        valid = self.valid_mask(x, mask)
        if self.export_mode or not bool(valid.all()):
            y = fpn_filter(
                self._fill_invalid(x, valid),
                self.taps,
                self.dims,
                self.border,
                not self.export_mode,
            )
            return torch.where(valid, y, x)
        return fpn_filter(x, self.taps, self.dims, self.border, True)
