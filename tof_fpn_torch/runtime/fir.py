r"""1-D FIR kernels along the last axis of a tensor (torch only; used by :mod:`.fpn_filter`).

Convention: ``y[n] = sum_k h[k] x[n + L // 2 - k]`` for ``L`` taps, i.e. the same as
``scipy.ndimage.convolve1d(x, h, mode=...)``. Every function here takes the *flipped* taps
``g = h[::-1]`` (a correlation kernel) and works on a (R, W) view whose rows are the lines.

Speed: a direct convolution costs ``L`` multiply-adds per sample and ``F.conv1d`` does not reach
BLAS speed for one long single-channel kernel. The rows are consecutive in memory, so the flattened
batch is one long signal. For float32 on CPU (inference) that signal, viewed as (n / 8, 8), is a
channels-last image whose 8 channels are its polyphase components; the FIR is then one 8-in,
32-out convolution with stride 4 and ``K = ceil((L + 31) / 8)`` taps (``8 K`` multiply-adds per
sample: 56 for 21 taps, 80 for 42) that oneDNN runs at GEMM speed, read straight from the input and
written straight into the output (:func:`fir_polyphase`). Other dtypes and devices cut the signal
into blocks of ``M >= L - 1`` samples; each block of output is one row of two small GEMMs with
banded Toeplitz matrices (:func:`fir_inplace`). Either way only the ``L - 1`` border columns of
each row, whose window crosses a row end, are then redone: the padding is folded into small
matrices and all row seams are one more GEMM (:func:`redo_borders`). With autograd, or when tracing
for export, the mathematically identical out-of-place :func:`fir_blocked` is used.

The small matrices depend only on the taps and the border mode: :func:`fir_operators` builds them
once, and :class:`~tof_fpn_torch.runtime.FPNFilter` keeps them as buffers.
"""

from __future__ import annotations

import torch
from torch.nn import functional as F

__all__ = [
    "BORDER_MODES",
    "fir_blocked",
    "fir_last",
    "fir_operators",
    "fir_polyphase",
    "pad_index",
]

BORDER_MODES: tuple[str, ...] = ("reflect", "replicate", "circular", "zeros")


def _phases() -> int:
    """Output samples per position of :func:`fir_polyphase` (a function: TorchScript reads no
    globals); also its minimum input: ``2 * _phases()`` samples."""
    return 32


def _in_phases() -> int:
    """Input samples per position (input channels) of :func:`fir_polyphase`."""
    return 8


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


def _split(length: int) -> tuple[int, int]:
    """``(left, right)`` extents of the window of ``length`` taps around the output sample."""
    right = length // 2
    return length - 1 - right, right


def _seam_operators(g: torch.Tensor, mode: str) -> list[torch.Tensor]:
    """``[seam, A_left, A_right]`` of :func:`redo_borders` (not ``circular``): ``A_left`` maps the
    first ``k`` columns of a row to its left border outputs, ``A_right`` the last ``k`` to the
    right ones, ``seam = [[A_right, 0], [0, A_left]]`` the end of one row and the start of the
    next to their ``L - 1`` outputs. ``k = L - 1``, or ``L`` for ``L = 2`` (whose reflected right
    neighbour lies one column further in). Independent of the row width ``W >= L``."""
    left, right = _split(g.shape[0])
    p = g.shape[0] - 1
    k = max(p, right + 1)
    a1, a2 = _border_operator(g, left, right, 2 * k, mode, k)
    a_left, a_right = a1[:, :left], a2[:, left:]
    seam = torch.zeros(2 * k, p, dtype=g.dtype, device=g.device)
    seam[:k, :right] = a_right
    seam[k:, right:] = a_left
    return [seam, a_left, a_right]


def polyphase_weight(g: torch.Tensor) -> torch.Tensor:
    """``W[q, p, 0, k] = g[k Pin + p - q]`` (0 outside), the channels-last (Q, Pin, 1, K) weight of
    :func:`fir_polyphase`, ``K = ceil((Q + L - 1) / Pin)``."""
    q_out, p_in = _phases(), _in_phases()
    length = g.shape[0]
    k_len = (q_out + length - 1 + p_in - 1) // p_in
    q = torch.arange(q_out, device=g.device).view(q_out, 1, 1)
    p = torch.arange(p_in, device=g.device).view(1, p_in, 1)
    j = torch.arange(k_len, device=g.device).view(1, 1, k_len)
    k = j * p_in + p - q
    inside = (k >= 0) & (k < length)
    gz = torch.cat([g, torch.zeros(1, dtype=g.dtype, device=g.device)])
    wt = gz[torch.where(inside, k, torch.full_like(k, length))]
    return wt.unsqueeze(2).contiguous(memory_format=torch.channels_last)


def fir_operators(taps: torch.Tensor, mode: str) -> list[torch.Tensor]:
    """The matrices of the fast paths for ``taps`` (not flipped) and a border mode:
    ``[polyphase weight (float32), seam, A_left, A_right]`` (the last three in the taps' dtype;
    empty for ``circular``, whose border matrices depend on the width). Built once per taps."""
    g = taps.detach().flip(0)
    poly = polyphase_weight(g.to(torch.float32))
    if mode == "circular" or g.shape[0] < 2:
        empty = g[:0]
        return [poly, empty, empty, empty]
    return [poly] + _seam_operators(g, mode)


def fir_blocked(x2: torch.Tensor, g: torch.Tensor, mode: str) -> torch.Tensor:
    """Out-of-place block-Toeplitz FIR along the last axis of (R, W); differentiable, exportable."""
    length = g.shape[0]
    left, right = _split(length)
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


def fir_inplace(
    x2: torch.Tensor, g: torch.Tensor, mode: str, ops: list[torch.Tensor]
) -> torch.Tensor:
    """Block-Toeplitz FIR along the last axis of a contiguous (R, W) written into one output
    buffer, no autograd. Needs ``W >= L`` and ``R * W >= L - 1 + M``."""
    length = g.shape[0]
    left, right = _split(length)
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
    redo_borders(x2, out2, g, mode, ops)
    return out2


def fir_polyphase(
    x2: torch.Tensor, g: torch.Tensor, mode: str, ops: list[torch.Tensor]
) -> torch.Tensor:
    """Polyphase FIR along the last axis of a contiguous float32 (R, W) as one strided
    multi-channel convolution.

    The flattened batch is one long signal ``x``; viewed as (n / Pin, Pin) it *is* a channels-last
    (1, Pin, 1, n / Pin) image whose channel ``p`` holds the phase ``x[m Pin + p]``, no copy. A
    convolution with stride ``Q / Pin`` and ``K = ceil((Q + L - 1) / Pin)`` taps gives ``Q``
    outputs per position: output channel ``q`` of position ``j`` is
    ``sum_{p, k} g[k Pin + p - q] x[(j Q / Pin - pad + k) Pin + p]``, i.e. the correlation at flat
    sample ``j Q + q - pad Pin``, ``K Pin`` multiply-adds per sample (56 for 21 taps, 80 for 42,
    against ``L`` for a direct loop but at GEMM speed). Its channels-last output is again a flat
    signal: ``pad`` zero blocks on both sides make the result a view of it, shifted by
    ``pad Pin - left``. Only row-border columns and the windows that reach the last ``n mod Pin``
    samples are then redone. Needs ``W >= L`` and ``R W >= 2 Q``.
    """
    q_out, p_in = _phases(), _in_phases()
    stride = q_out // p_in
    length = g.shape[0]
    left, right = _split(length)
    k_len = (q_out + length - 1 + p_in - 1) // p_in
    r, w = x2.shape[0], x2.shape[1]
    n = r * w
    m = n // p_in
    pad = (left + p_in - 1) // p_in
    while ((m + 2 * pad - k_len) // stride + 1) * q_out < pad * p_in - left + n:
        pad += 1
    xf = x2.reshape(-1)
    xi = xf[: m * p_in].view(1, 1, m, p_in).permute(0, 3, 1, 2)
    xi = xi.contiguous(memory_format=torch.channels_last)  # already is: no copy
    y = F.conv2d(xi, ops[0].to(x2.device), stride=(1, stride), padding=(0, pad))
    flat = y.permute(0, 2, 3, 1).reshape(-1)  # channels-last output: a view
    start = pad * p_in - left
    out = flat[start : start + n]
    s0 = max(m * p_in - right, left)  # from here on windows reach the n mod Pin samples left out
    if s0 < n - right:
        out[s0 : n - right] = xf[s0 - left :].unfold(0, length, 1).matmul(g)
    out2 = out.view(r, w)
    redo_borders(x2, out2, g, mode, ops)
    return out2


def redo_borders(
    x2: torch.Tensor, out2: torch.Tensor, g: torch.Tensor, mode: str, ops: list[torch.Tensor]
) -> None:
    """Overwrite the ``left`` + ``right`` border columns of contiguous ``out2`` (R, W) from
    contiguous ``x2``: their windows cross a row end.

    The padding is a linear map of the row's end columns, so it is folded into small matrices.
    Except for ``circular``, the left outputs depend on the first ``k`` columns only and the right
    outputs on the last ``k``. The end of row ``i`` and the start of row ``i + 1`` are one
    contiguous run of ``2 k`` samples, and their outputs (right border of ``i``, left border of
    ``i + 1``) one contiguous run of ``L - 1``: all seams are one GEMM from a strided view of the
    input straight into a strided view of the output (no gather, no copy), plus the two outer ends.
    """
    left, right = _split(g.shape[0])
    p = g.shape[0] - 1
    r, w = x2.shape[0], x2.shape[1]
    if mode != "circular":
        seam = ops[1].to(device=x2.device, dtype=x2.dtype)
        a_left = ops[2].to(device=x2.device, dtype=x2.dtype)
        a_right = ops[3].to(device=x2.device, dtype=x2.dtype)
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


def fir_last(
    x: torch.Tensor, taps: torch.Tensor, mode: str, ops: list[torch.Tensor], fast: bool
) -> torch.Tensor:
    """Convolve ``x`` (..., W) with ``taps`` along the last axis, ``convolve1d`` centring.

    ``ops`` are :func:`fir_operators` of ``taps`` and ``mode`` (an empty list builds them here when
    a fast path needs them). ``fast`` allows the in-place inference paths.
    """
    length = taps.shape[0]
    shape = x.shape
    w = shape[-1]
    g = taps.flip(0).to(device=x.device, dtype=x.dtype)
    if length == 1:
        return x * g[0]
    x2 = x.reshape(-1, w)
    n = x2.shape[0] * w
    polyphase = x.dtype == torch.float32 and x.device.type == "cpu" and n >= 2 * _phases()
    if fast and w >= length and (polyphase or n >= length - 1 + _block_size(length)):
        if len(ops) == 0:
            ops = fir_operators(taps, mode)
        if polyphase:
            y = fir_polyphase(x2.contiguous(), g, mode, ops)
        else:
            y = fir_inplace(x2.contiguous(), g, mode, ops)
    else:
        y = fir_blocked(x2, g, mode)
    return y.reshape(shape)
