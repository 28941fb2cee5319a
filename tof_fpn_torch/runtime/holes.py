r"""Invalid pixels and isolated outliers in the FPN filter (torch only, TorchScript-clean).

:class:`~tof_fpn_torch.runtime.FPNFilter` filters along one axis at a time; along that axis, on
every line (a row for ``dim=-1``, a column for ``dim=-2``):

1. **Usable pixels** are the valid ones (:func:`~tof_fpn_torch.runtime.valid_mask` and the
   caller's ``mask``) that are not **isolated outliers**: a valid pixel more than
   :func:`outlier_ratio` (3) times as far as each valid neighbour at distance 1 on the line, or
   less than a third as far as each of them (a 3.6 m return on a 0.35 m wall). A pixel without a
   valid neighbour there is not an outlier. The rule is scale-free (metres or millimetres give the
   same pixels), and a line whose usable depths stay within a factor 3 has none.
2. **Fill**: the line is cut into blocks of 8 pixels from its start (the last one may be shorter);
   ``S_b`` is the sum of the usable depths of block ``b``, ``N_b`` their number. Both are smoothed
   along the line with the triangular weights ``K + 1 - |j|``, ``|j| <= K``, ``K =
   ceil((L // 2) / 8)`` for ``L`` taps, and every pixel that is not usable gets ``S'_b / N'_b`` of
   its block ``b``: a local mean of the usable depths within ``8 K + 7`` pixels. ``N'_b`` is
   positive for every pixel within ``L // 2`` of a usable one, so each value a valid output reads
   is a mean of usable depths; the other pixels get some positive value that no valid output
   reads.
3. The FIR runs on the filled line, and every pixel that is not usable gets its input back
   (invalid ones bit for bit, outliers unchanged).

Hence the output at a usable pixel ``n`` is ``sum_k h_k f_{n-k}`` with ``f`` the filled line, and
because ``sum_k (h_k - delta_k) = H(0) - 1``,

    |y_n - x_n| <= sum_k |h_k - delta_k| * max_k |f_{n-k} - x_n| + |H(0) - 1| * |x_n|,

where every ``f`` is a usable depth or a mean of usable depths within ``L // 2 + 8 K + 7`` pixels of
``n`` on its line: **a valid pixel moves by at most ``sum |h - delta|`` (1.37 for the default
design) times the largest difference between its depth and a usable depth within that reach**
(plus ``|H(0) - 1| |x_n|``, 0 for unit-DC designs). An outlier cannot move its neighbours, and no
depth from across a hole wider than that reach enters. ``tests/test_fpn_holes.py`` checks the fill,
the filter and this bound against a NumPy implementation of the same rule.

Why not the plain normalised convolution with the filter itself (``h * (v x) / h * v``)? The notch
taps have negative lobes: next to some hole patterns ``sum`` of the valid taps falls to 0.3 (and
below 0 for the 42-tap design), amplifying the noise three-fold or worse; the fill above is a
convex mean, and it costs memory passes but no second convolution.
"""

from __future__ import annotations

import torch

from .fir import fir_last
from .validity import valid_mask

__all__ = [
    "certified",
    "fill_lines",
    "fill_reach",
    "holed_exact",
    "holed_lines",
    "isolated_outliers",
    "outlier_ratio",
    "tap_gains",
]


def outlier_ratio() -> float:
    """How many times deeper (or shallower) than each neighbour an isolated outlier is."""
    return 3.0


def _block() -> int:
    """Pixels per block of the coarse fill (a function: TorchScript reads no globals)."""
    return 8


def fill_reach(length: int) -> int:
    """``K``: the smoothing half-width in blocks for ``length`` taps (reaches ``length // 2``)."""
    b = _block()
    return (length // 2 + b - 1) // b


def _block_sums(v: torch.Tensor, exact_shape: bool) -> torch.Tensor:
    """(R, W) -> (R, ceil(W / 8)) sums over blocks of 8 columns (the last one may be shorter).
    ``exact_shape``: no Python branch on the width (traced for export with dynamic shapes)."""
    b = _block()
    r, w = v.shape[0], v.shape[1]
    nb = (w + b - 1) // b
    if not exact_shape and nb * b == w and v.is_contiguous():  # a matrix-vector product
        return v.view(-1, b).matmul(torch.ones(b, dtype=v.dtype, device=v.device)).view(r, nb)
    v = torch.cat([v, v.new_zeros(r, nb * b - w)], 1)
    return v.reshape(r, nb, b).sum(-1)


def _triangle(nb: int, reach: int, like: torch.Tensor) -> torch.Tensor:
    """(nb, nb) band ``max(K + 1 - |i - j|, 0)``: the block smoothing as a matrix."""
    i = torch.arange(nb, device=like.device)
    d = (i.view(-1, 1) - i.view(1, -1)).abs()
    return (reach + 1 - d).clamp_min(0).to(like.dtype)


def fill_lines(
    x0: torch.Tensor,
    v: torch.Tensor,
    reach: int,
    exact_shape: bool,
    out: torch.Tensor | None = None,
) -> torch.Tensor:
    """The filled lines of step 2 in the module docstring.

    Args:
        x0: (R, W) depth, 0 where not usable (no NaN / inf).
        v: (R, W) 1.0 where usable, 0.0 elsewhere.
        reach: ``K`` of :func:`fill_reach`.
        exact_shape: take the branch-free, export-safe route (see :func:`_block_sums`).
        out: optional contiguous (R, W) buffer for the result (eager inference).

    Returns:
        (R, W): ``x0`` where ``v == 1`` (exactly), the block fill elsewhere.
    """
    b = _block()
    r, w = x0.shape[0], x0.shape[1]
    both = torch.cat([_block_sums(x0, exact_shape), _block_sums(v, exact_shape)])
    nb = both.shape[1]
    both = both.matmul(_triangle(nb, reach, both))
    sums, counts = both[:r], both[r:]
    fill = sums / counts.clamp_min(0.5)  # counts are whole numbers: 0, or >= 1
    # no valid output reads the others; eager: the largest fill, so that they stay in the range
    # of the valid depths (exported graphs: any positive value)
    if exact_shape:
        fill = torch.where(counts > 0, fill, torch.ones_like(fill))
    elif bool((counts < 0.5).any()):
        fill = torch.where(counts > 0, fill, fill.amax((0, 1), keepdim=True))
    if not exact_shape and nb * b == w:  # a broadcast view: no (R, W) fill buffer
        args = (fill.unsqueeze(-1), x0.view(r, nb, b), v.view(r, nb, b))
        if out is None:
            return torch.lerp(args[0], args[1], args[2]).view(r, w)
        return torch.lerp(args[0], args[1], args[2], out=out.view(r, nb, b)).view(r, w)
    cols = torch.div(torch.arange(w, device=x0.device), b, rounding_mode="floor")
    if out is None:
        return torch.lerp(fill.index_select(1, cols), x0, v)
    return torch.lerp(fill.index_select(1, cols), x0, v, out=out)


def _pad1(t: torch.Tensor) -> torch.Tensor:
    """One zero column on each side (cat, not F.pad: exports to opset 17)."""
    z = t.new_zeros(t.shape[0], 1)
    return torch.cat([z, t, z], 1)


def isolated_outliers(x0: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Step 1's outliers: (R, W) bool, True where a valid pixel is more than :func:`outlier_ratio`
    times as far as each valid neighbour at distance 1 along the last axis, or less than its
    inverse times as far as each.

    Args:
        x0: (R, W) depth, 0 where invalid (no NaN / inf).
        v: (R, W) 1.0 where valid, 0.0 elsewhere.
    """
    xp = _pad1(x0)
    far = torch.maximum(xp[:, :-2], xp[:, 2:])  # deepest valid neighbour (0: none)
    inv = v / (x0 + (1.0 - v))  # 1 / depth where valid, 0 elsewhere
    ip = _pad1(inv)
    near = torch.maximum(ip[:, :-2], ip[:, 2:])  # 1 / the nearest valid neighbour (0: none)
    ratio = outlier_ratio()
    deep = (x0 > ratio * far) & (far > 0)
    shallow = (inv > ratio * near) & (near > 0)
    return deep | shallow


def certified(lo: float, hi: float, gains: tuple[float, float]) -> bool:
    """Every FIR output of inputs in [lo, hi] is valid: ``sum h+ lo - sum |h-| hi`` stays above the
    float rounding of the sums, and the largest output is finite."""
    pos, neg = gains
    margin = 1e-4 * (pos + neg) * hi
    return pos * lo - neg * hi > margin and (pos + neg) * hi < 1e37


def _chunk_samples() -> int:
    """Samples per chunk of :func:`holed_lines` (a function: TorchScript reads no globals)."""
    return 1 << 20


def holed_lines(
    x2: torch.Tensor,
    valid2: torch.Tensor | None,
    taps: torch.Tensor,
    border: str,
    ops: list[torch.Tensor],
    reach: int,
    gains: tuple[float, float],
    zeros: bool,
) -> torch.Tensor:
    """Inference: fill, filter and write back (R, W) lines in chunks of about 1 M samples, so that
    the temporaries stay small (in the cache, and reused by the allocator: a fresh frame-sized
    buffer costs its page faults on every call). ``valid2`` None: all valid; ``zeros``: the invalid
    pixels are exactly the +0.0 ones. Outliers are searched only in chunks whose values span more
    than a factor 3 (elsewhere there can be none)."""
    r, w = x2.shape[0], x2.shape[1]
    out = torch.empty_like(x2)
    rows = max(1, _chunk_samples() // w)
    for r0 in range(0, r, rows):
        r1 = min(r, r0 + rows)
        xc = x2[r0:r1]
        if valid2 is None or zeros:
            v = torch.gt(xc, 0.0, out=torch.empty_like(xc))
            x0 = xc
        else:
            vb = valid2[r0:r1]
            v = vb.to(xc.dtype)
            x0 = torch.where(vb, xc, torch.zeros_like(xc))
        filled = fill_lines(x0, v, reach, False)
        lo, hi = torch.aminmax(filled)
        if not bool(hi < outlier_ratio() * lo):
            odd = isolated_outliers(x0, v)
            if bool(odd.any()):
                v.masked_fill_(odd, 0.0)
                filled = fill_lines(x0 * v, v, reach, False)
                lo, hi = torch.aminmax(filled)
        yc = fir_last(filled, taps, border, ops, True)
        oc = out[r0:r1]
        if valid2 is None or zeros:  # every unusable value is finite and not -0.0: lerp is exact
            torch.lerp(xc, yc, v, out=oc)
        else:
            torch.where(v > 0, yc, xc, out=oc)
        if not certified(float(lo), float(hi), gains):  # a valid pixel must stay valid
            oc.copy_(torch.where((v > 0) & ~valid_mask(oc), xc, oc))
    return out


def holed_exact(
    x2: torch.Tensor,
    valid2: torch.Tensor,
    taps: torch.Tensor,
    border: str,
    ops: list[torch.Tensor],
    reach: int,
    fast: bool,
) -> torch.Tensor:
    """The same rule branch-free and out of place (tracing for export, autograd)."""
    v = valid2.to(x2.dtype)
    x0 = torch.where(valid2, x2, torch.zeros_like(x2))
    v = v.masked_fill(isolated_outliers(x0, v), 0.0)
    x0 = x0 * v
    y = fir_last(fill_lines(x0, v, reach, True), taps, border, ops, fast)
    out = torch.where(v > 0, y, x2)
    return torch.where(valid2 & ~valid_mask(out), x2, out)


def tap_gains(taps: torch.Tensor) -> tuple[float, float]:
    t = taps.detach()
    return float(t.clamp_min(0.0).sum()), float(-t.clamp_max(0.0).sum())
