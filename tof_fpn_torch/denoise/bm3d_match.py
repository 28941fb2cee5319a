r"""Block matching of :mod:`tof_fpn_torch.denoise.bm3d_core` (torch only, TorchScript-clean).

Reference blocks on a grid of ``step`` pixels, each compared with every block within ``radius``
pixels (a ``(2 radius + 1)^2`` window, clipped to the image), with
``|a - b|^2 = |a|^2 + |b|^2 - 2 a.b``:

* on the pixels (exact distances, :func:`_scores_window`): the dot products per offset over the
  whole image (the product of the image with its shifted copy, summed over the reference
  blocks), the offsets of one column of the window in one op each;
* on features (the ``q x q`` lowest DCT frequencies of every block): references are processed
  in tiles of ``tile x tile`` that share one candidate region, one batched matrix product per
  tile.

The ``n2`` best candidates of every reference are then selected exactly in two stages
(:func:`_select`, :func:`_select_window`)."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

__all__ = ["low_frequencies", "match"]


def low_frequencies(n: int, q: int) -> torch.Tensor:
    """Indices (q^2,) of the coefficients with ``kx, ky < q`` (order ``kx * n + ky``)."""
    k = torch.arange(n * n)
    return torch.nonzero((torch.div(k, n, rounding_mode="floor") < q) & (k % n < q)).flatten()


def _grid(Hc: int, Wc: int, step: int, tile: int) -> list[int]:
    ny = (Hc - 1) // step + 1
    nx = (Wc - 1) // step + 1
    return [ny, nx, (ny + tile - 1) // tile, (nx + tile - 1) // tile]


def _scores_features(
    feat: torch.Tensor, step: int, radius: int, tile: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """Block distances up to the reference's norm on a (Hc, Wc, f) channels-last feature map:
    (T, tile^2, span^2) ``|c|^2 - 2 r.c`` per tile of references and candidate of the tile's
    region (``inf``-like outside; one batched matrix product per tile, the candidate matrices
    are one copy of contiguous rows), and the (N,) squared norms of the references."""
    Hc, Wc, f = feat.shape
    ny, nx, ty, tx = _grid(Hc, Wc, step, tile)
    span = step * (tile - 1) + 2 * radius + 1
    ch, cw = step * tile * ty + 2 * radius, step * tile * tx + 2 * radius
    fp = torch.zeros(ch, cw, f, dtype=feat.dtype, device=feat.device)
    fp[radius : radius + Hc, radius : radius + Wc] = feat
    fnorm = feat.square().sum(-1)
    norm = torch.full((ch, cw), 1e30, dtype=feat.dtype, device=feat.device)
    norm[radius : radius + Hc, radius : radius + Wc] = fnorm
    st = fp.stride()
    cand = fp.as_strided(
        (ty, tx, span, span, f), (step * tile * st[0], step * tile * st[1], st[0], st[1], 1)
    ).reshape(ty * tx, span * span, f)
    ns = norm.stride()
    cnorm = norm.as_strided((ty, tx, span, span), (step * tile * ns[0], step * tile, ns[0], 1))
    rs = fp[radius:, radius:]
    ref = rs.as_strided(
        (ty, tile, tx, tile, f),
        (step * tile * st[0], step * st[0], step * tile * st[1], step * st[1], 1),
    )
    ref = ref.permute(0, 2, 1, 3, 4).reshape(ty * tx, tile * tile, f)
    scores = torch.baddbmm(
        cnorm.reshape(ty * tx, 1, span * span), ref, cand.transpose(1, 2), alpha=-2.0
    )
    return scores, fnorm[::step, ::step].reshape(-1)


def _select(
    scores: torch.Tensor,
    rnorm: torch.Tensor,
    Hc: int,
    Wc: int,
    step: int,
    radius: int,
    tile: int,
    n2: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The ``n2`` best matches of every reference in its own window: ``(dist, idx)``, each
    (N, n2), ascending squared distances (the reference itself first, at 0; ``inf`` outside the
    image) and flat block positions ``y * Wc + x``; N = ny * nx references, row-major.

    Exact two-stage selection: the window's rows are cut into runs of ``g`` candidates; the
    ``n2`` runs with the smallest minima contain the ``n2`` best candidates (a candidate outside
    them has ``n2`` run minima, distinct candidates, at or below it), so only those
    ``n2 * g`` candidates are ranked (torch's ``topk`` costs ~20 ns per element)."""
    ny, nx, ty, tx = _grid(Hc, Wc, step, tile)
    win = 2 * radius + 1
    span = step * (tile - 1) + win
    ds = scores.stride()
    st = [tx * ds[0], ds[0], tile * ds[1] + step * span, ds[1] + step, span, 1]
    own = scores.as_strided((ty, tx, tile, tile, win, win), st)
    own[:, :, :, :, radius, radius] = -1e30  # the reference itself comes first
    g = 1
    for cand in [5, 4, 3, 2]:
        if g == 1 and win % cand == 0:
            g = cand
    k = min(n2, win * win)
    # offset of every reference's window in ``scores`` (N,), row-major over the references
    ti = torch.arange(ty * tile, device=scores.device)[:ny]
    tj = torch.arange(tx * tile, device=scores.device)[:nx]
    oy = torch.div(ti, tile, rounding_mode="floor") * st[0] + (ti % tile) * st[2]
    ox = torch.div(tj, tile, rounding_mode="floor") * st[1] + (tj % tile) * st[3]
    base = (oy[:, None] + ox[None, :]).reshape(-1, 1)
    flat = scores.reshape(-1)
    if g > 1 and n2 * g < win * win:
        runs = scores.as_strided((ty, tx, tile, tile, win, win // g, g), st[:5] + [g, 1])
        mins = runs.amin(-1).permute(0, 2, 1, 3, 4, 5).reshape(ty * tile, tx * tile, -1)
        mins = mins[:ny, :nx].reshape(ny * nx, -1)
        _, r = torch.topk(mins, k, dim=1, largest=False, sorted=False)  # (N, k) runs
        ry_ = torch.div(r, win // g, rounding_mode="floor")
        rx_ = (r % (win // g)) * g
        off = torch.arange(g, device=scores.device)
        wy = ry_[:, :, None].expand(-1, -1, g).reshape(ny * nx, k * g)
        wx = (rx_[:, :, None] + off).reshape(ny * nx, k * g)
        vals = flat.index_select(0, (base + wy * span + wx).reshape(-1)).reshape(ny * nx, k * g)
        d, jj = torch.topk(vals, k, dim=1, largest=False, sorted=True)
        j = torch.gather(wy, 1, jj) * win + torch.gather(wx, 1, jj)
    else:
        j = torch.arange(win * win, device=scores.device)
        wy = torch.div(j, win, rounding_mode="floor")
        pos = (base + (wy * span + j % win)[None, :]).reshape(-1)
        vals = flat.index_select(0, pos).reshape(ny * nx, win * win)
        d, j = torch.topk(vals, k, dim=1, largest=False, sorted=True)
    return _positions(d, j, rnorm, Hc, Wc, step, radius)


def _window_sums(src: torch.Tensor, n: int, step: int, m: int, out: torch.Tensor) -> torch.Tensor:
    """``out[:, :, j] = sum_{u < n} src[:, :, step j + u]`` for ``j < m`` (3-D tensors): sums of
    shifted copies by doubling, the last level only at the ``m`` output positions."""
    parts: list[torch.Tensor] = []
    starts: list[int] = []
    block = src
    span = 1
    rem = n
    pos = 0
    while rem > 0:
        if rem % 2 == 1:
            parts.append(block)
            starts.append(pos)
            pos += span
        rem = rem // 2
        if rem == 1:  # the last block as its two halves
            parts.append(block)
            starts.append(pos)
            parts.append(block)
            starts.append(pos + span)
            rem = 0
        elif rem > 1:
            L = block.shape[2] - span
            block = torch.add(block.narrow(2, 0, L), block.narrow(2, span, L))
            span *= 2
    e = step * (m - 1) + 1
    if len(parts) == 1:
        return out.copy_(parts[0].narrow(2, starts[0], e)[:, :, ::step])
    a = parts[0].narrow(2, starts[0], e)[:, :, ::step]
    torch.add(a, parts[1].narrow(2, starts[1], e)[:, :, ::step], out=out)
    for i in range(2, len(parts)):
        out.add_(parts[i].narrow(2, starts[i], e)[:, :, ::step])
    return out


def _scores_window(
    x: torch.Tensor, n: int, step: int, radius: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """Exact block distances up to the reference's norm: (win^2, N) ``|c|^2 - 2 r.c`` of every
    candidate offset (``win = 2 radius + 1``, offset ``(wy, wx)`` at row ``wx * win + wy``) and
    reference (row-major grid; ``~1e30`` outside the image), and the (N,) squared norms of the
    references.

    The dot products are computed per offset over the whole image (``x(p) x(p + t)`` summed
    over each reference block: a product, then sums along the columns at the reference rows
    and along the rows at the reference columns), the offsets of one column of the window in
    one op each: each product is computed once, not once per overlapping tile."""
    H, W = x.shape
    Hc, Wc = H - n + 1, W - n + 1
    ny = (Hc - 1) // step + 1
    nx = (Wc - 1) // step + 1
    win = 2 * radius + 1
    x = x - x.mean()  # distances do not change; the products lose less precision
    Wp = W + 2 * radius
    xp = torch.zeros((H + 2 * radius) * Wp, dtype=x.dtype, device=x.device)
    xp.view(H + 2 * radius, Wp)[radius : radius + H, radius : radius + W] = x
    bnorm = F.avg_pool2d((x * x).reshape(1, 1, H, W), n, stride=1).reshape(Hc, Wc) * (n * n)
    Wn = Wc + 2 * radius
    norm = torch.full((Hc + 2 * radius, Wn), 1e30, dtype=x.dtype, device=x.device)
    norm[radius : radius + Hc, radius : radius + Wc] = bnorm
    a = x.reshape(1, H, W).expand(win, H, W)
    prod = torch.empty(win, H, W, dtype=x.dtype, device=x.device)
    cols = torch.empty(win, ny, W, dtype=x.dtype, device=x.device)
    scores = torch.empty(win, win, ny, nx, dtype=x.dtype, device=x.device)  # (wx, wy, i, j)
    for wx in range(win):
        b = xp.as_strided((win, H, W), (Wp, Wp, 1), wx)  # rows wy + y, columns wx + x
        torch.mul(a, b, out=prod)
        torch.sum(prod.as_strided((win, ny, n, W), (H * W, step * W, W, 1)), 2, out=cols)
        sw = _window_sums(cols, n, step, nx, scores[wx])
        cn = norm.as_strided((win, ny, nx), (Wn, step * Wn, step), wx)  # |c|^2
        torch.add(cn, sw, alpha=-2.0, out=sw)
    return scores.reshape(win * win, ny * nx), bnorm[::step, ::step].reshape(-1)


def _select_window(
    scores: torch.Tensor,
    rnorm: torch.Tensor,
    Hc: int,
    Wc: int,
    step: int,
    radius: int,
    n2: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`_select` on the (win^2, N) layout of :func:`_scores_window` (runs of ``g``
    candidates along the window's columns)."""
    N = scores.shape[1]
    win = 2 * radius + 1
    scores[radius * win + radius] = -1e30  # the reference itself comes first
    g = 1
    for cand in [5, 4, 3, 2]:
        if g == 1 and win % cand == 0:
            g = cand
    k = min(n2, win * win)
    if g > 1 and n2 * g < win * win:
        mins = scores.view(win * (win // g), g, N).amin(1).t()
        _, r = torch.topk(mins, k, dim=1, largest=False, sorted=False)  # (N, k) runs
        off = torch.arange(g, device=scores.device)
        cand = (r[:, :, None] * g + off).reshape(N, k * g)  # run r: rows r g .. r g + g - 1
        ref = torch.arange(N, device=scores.device).reshape(N, 1)
        vals = scores.reshape(-1).index_select(0, (cand * N + ref).reshape(-1)).reshape(N, -1)
        d, jj = torch.topk(vals, k, dim=1, largest=False, sorted=True)
        o = torch.gather(cand, 1, jj)
    else:
        d, o = torch.topk(scores.t(), k, dim=1, largest=False, sorted=True)
    j = torch.remainder(o, win) * win + torch.div(o, win, rounding_mode="floor")
    return _positions(d, j, rnorm, Hc, Wc, step, radius)


def _positions(
    d: torch.Tensor,
    j: torch.Tensor,
    rnorm: torch.Tensor,
    Hc: int,
    Wc: int,
    step: int,
    radius: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """``(dist, idx)`` from the selected scores ``d`` and window offsets ``j`` (N, k)."""
    ny = (Hc - 1) // step + 1
    nx = (Wc - 1) // step + 1
    win = 2 * radius + 1
    d = (d + rnorm[:, None]).clamp_min(0.0)
    d[:, 0] = 0.0
    ry = (torch.arange(ny, device=d.device) * step).repeat_interleave(nx)
    rx = (torch.arange(nx, device=d.device) * step).repeat(ny)
    cy = ry[:, None] - radius + torch.div(j, win, rounding_mode="floor")
    cx = rx[:, None] - radius + torch.remainder(j, win)
    inside = (cy >= 0) & (cy < Hc) & (cx >= 0) & (cx < Wc)
    d = torch.where(inside, d, torch.full_like(d, math.inf))
    idx = torch.where(inside, cy * Wc + cx, torch.zeros_like(cy))
    return d, idx


def match(
    img: torch.Tensor,
    coef: torch.Tensor,
    features: int,
    n: int,
    step: int,
    radius: int,
    tile: int,
    n2: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Block matching on the pixels (``features >= n^2``) or on the ``q x q`` lowest DCT
    frequencies (``features = q^2``) of ``img`` / its coefficients ``coef``."""
    H, W = img.shape
    Hc, Wc = H - n + 1, W - n + 1
    if features >= n * n:
        scores, rnorm = _scores_window(img, n, step, radius)
        return _select_window(scores, rnorm, Hc, Wc, step, radius, n2)
    q = int(round(math.sqrt(features)))
    low = low_frequencies(n, q).to(coef.device)
    feat = coef.index_select(1, low).reshape(Hc, Wc, q * q)
    scores, rnorm = _scores_features(feat, step, radius, tile)
    return _select(scores, rnorm, Hc, Wc, step, radius, tile, n2)
