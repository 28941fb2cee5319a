r"""How much column stripe a frame has, measured so that white noise does not count (torch).

**Column-stripe energy.** Let ``HP`` be the depth minus its mean over ``width`` neighbouring valid
pixels of the same row (a horizontal high-pass; scene structure wider than ``width`` columns does
not enter), and ``p_top(x)``, ``p_bot(x)`` the means of ``HP`` down column ``x`` over the pixels
of a region in the top and in the bottom part of the rows. The energy is their covariance over the
columns,

    ``E = mean_x (p_top(x) - mean p_top) (p_bot(x) - mean p_bot)``   (depth units squared).

A column offset is the same in both parts and adds its variance to ``E``; white noise and
anything confined to one part are independent between them and add nothing in expectation. ``E``
can be negative (no common pattern; e.g. after a correction estimated from all rows, whose noise
enters both parts with opposite signs, ``E`` falls about ``(var p_top + var p_bot) / 4`` below
zero). The region should leave out strong scene structure (:func:`structure_mask`).

**Low-pass change.** The RMS over the valid pixels of the change ``after - before`` averaged over
``size x size`` valid pixels: how much a correction moves the depth at scales above ``size``.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ..runtime.noise import mad_to_sigma
from ..runtime.validity import valid_mask

__all__ = [
    "StripeEnergy",
    "column_stripe_energy",
    "energy_before_after",
    "lowpass_change",
    "quiet_mask",
    "row_highpass",
    "structure_mask",
]


def _check(depth: torch.Tensor, name: str = "depth") -> None:
    if not isinstance(depth, torch.Tensor) or depth.dim() != 4 or not depth.is_floating_point():
        raise ValueError(
            f"{name} must be a floating (B, C, H, W) tensor, got "
            f"{getattr(depth, 'shape', type(depth))}"
        )


def _cumsum_ext(x: torch.Tensor, pad: int) -> torch.Tensor:
    """The cumulative sums of ``x`` along its last axis, ``pad + 1`` zeros before and the total
    ``pad`` times after: ``ext[..., j + pad + 1]`` is the sum of ``x[..., : j + 1]`` for every ``j``
    from ``-pad - 1`` to ``n - 1 + pad``, clipped to the line (bool ``x``: int32 counts)."""
    n = x.shape[-1]
    dtype = torch.int32 if x.dtype == torch.bool else x.dtype
    ext = torch.empty(*x.shape[:-1], n + 2 * pad + 1, dtype=dtype, device=x.device)
    ext[..., : pad + 1] = 0
    torch.cumsum(x, -1, dtype=dtype, out=ext[..., pad + 1 : pad + 1 + n])
    ext[..., pad + 1 + n :] = ext[..., pad + n : pad + n + 1]
    return ext


def _window(ext: torch.Tensor, n: int, pad: int, before: int, after: int) -> torch.Tensor:
    """From :func:`_cumsum_ext` (``before``, ``after`` <= ``pad``): the sum over
    ``[i - before, i + after]`` at every ``i`` of the ``n`` samples, zero beyond the ends."""
    return (
        ext[..., pad + after + 1 : pad + after + 1 + n] - ext[..., pad - before : pad - before + n]
    )


def _window_sum(x: torch.Tensor, dim: int, before: int, after: int) -> torch.Tensor:
    """The sum of ``x`` over ``[i - before, i + after]`` along ``dim`` at every ``i``, the samples
    beyond the ends counting 0 (a box filter with zero padding), from one cumulative sum: the cost
    does not grow with the window. Exact for bool ``x`` (counts); floats accumulate along the
    line, so centre them first where the window's sums are far smaller than the line's."""
    x = x.movedim(dim, -1)
    n = x.shape[-1]
    if n == 0:
        return x.clone().movedim(-1, dim)
    pad = max(before, after)
    return _window(_cumsum_ext(x, pad), n, pad, before, after).movedim(-1, dim)


def _dilate(mask: torch.Tensor, radius: int) -> torch.Tensor:
    """``mask`` (bool) grown by ``radius`` pixels along rows and columns (a square of side
    ``2 radius + 1``, as a max pool would; from counts, exact)."""
    grown = _window_sum(mask, -1, radius, radius) > 0
    return _window_sum(grown, -2, radius, radius) > 0


def _check_width(width) -> None:
    if isinstance(width, bool) or not isinstance(width, int) or width < 3 or width % 2 == 0:
        raise ValueError(f"width must be an odd int >= 3, got {width!r}")


def _counts(v: torch.Tensor, widths: tuple[int, ...]) -> dict[int, torch.Tensor]:
    """Per width: the number of valid pixels within ``width // 2`` columns in the row (float64,
    exact; at least 1 at a valid pixel, 0 possible elsewhere)."""
    n, pad = v.shape[-1], max(widths) // 2
    ext = _cumsum_ext(v.to(torch.float64), pad)
    return {w: _window(ext, n, pad, w // 2, w // 2) for w in widths}


def _highpasses(
    depth: torch.Tensor,
    v: torch.Tensor,
    widths: tuple[int, ...],
    counts: dict[int, torch.Tensor] | None = None,
) -> list[torch.Tensor]:
    """:func:`row_highpass` of ``depth`` over the valid pixels ``v`` for each of ``widths``, from
    one cumulative sum along the rows (``counts``: :func:`_counts` of ``v``, if known)."""
    n = depth.shape[-1]
    if n == 0:
        return [torch.zeros_like(depth) for _ in widths]
    counts = _counts(v, widths) if counts is None else counts
    # each row less the mean of its valid pixels (the high-pass does not see a row's offset):
    # the cumulative sums then hold deviations, not the depth itself
    # in place where it can (fresh frame-sized buffers cost page faults); all float64 (an op on
    # mixed dtypes takes a slow path)
    invalid = ~v
    x = depth.to(torch.float64, copy=True).masked_fill_(invalid, 0.0)  # never the input
    x.sub_(x.sum(-1, keepdim=True) / v.sum(-1, keepdim=True).clamp_min(1))
    x.masked_fill_(invalid, 0.0)
    pad = max(widths) // 2
    sums = _cumsum_ext(x, pad)
    out = []
    for width in widths:
        r = width // 2
        # x less the mean around each pixel (0 / 0 at an invalid pixel without valid neighbours,
        # set to 0 below with every invalid pixel)
        hp = _window(sums, n, pad, r, r).div_(counts[width])
        torch.sub(x, hp, out=hp)
        out.append(hp.to(depth.dtype).masked_fill_(invalid, 0.0))
    return out


def row_highpass(
    depth: torch.Tensor, width: int = 9, valid: torch.Tensor | None = None
) -> torch.Tensor:
    """``depth`` minus the mean of the valid pixels within ``width // 2`` columns in its row (0 at
    invalid pixels). ``width``: odd int >= 3."""
    _check(depth)
    _check_width(width)
    v = valid_mask(depth) if valid is None else valid
    return _highpasses(depth, v, (width,))[0]


def _structure(
    hp: torch.Tensor, v: torch.Tensor, threshold: float, dilate: int, size=None
) -> torch.Tensor:
    """``v`` less the pixels within ``dilate`` of one whose ``|hp|`` (``size``, if known) is
    above ``threshold``."""
    strong = (hp.abs() if size is None else size) > threshold
    if dilate > 0 and bool(strong.any()):
        strong = _dilate(strong, dilate)
    return v & ~strong


def structure_mask(
    depth: torch.Tensor, threshold: float, width: int = 15, dilate: int = 6
) -> torch.Tensor:
    """Valid pixels away from strong scene structure: ``|row_highpass(depth, width)| >
    threshold`` (depth units) dilated by ``dilate`` pixels is left out."""
    _check(depth)
    v = valid_mask(depth)
    return _structure(row_highpass(depth, width, v), v, threshold, dilate)


def _lower_median(a: torch.Tensor, v: torch.Tensor) -> float:
    """The median of ``a`` over ``v`` (the lower of the two middle values, as ``torch.median``;
    ``v`` has a pixel)."""
    k = (int(v.sum()) - 1) // 2
    a = torch.where(v, a, float("inf")).reshape(-1)  # the invalid pixels sort last
    if a.device.type == "cpu":  # NumPy's selection (in place: ``a`` is a fresh tensor), a
        arr = a.detach().numpy()  # seventh of kthvalue's time on the CPU
        arr.partition(k)
        return float(arr[k])
    return float(a.kthvalue(k + 1).values)  # a selection, not a sort


def _quiet(v: torch.Tensor, hp: torch.Tensor, sigmas: float) -> torch.Tensor:
    """:func:`quiet_mask` from the valid pixels ``v`` and the ``width`` high-pass ``hp``."""
    if not bool(v.any()):
        return v
    size = hp.abs()
    scale = float(mad_to_sigma(torch.tensor(_lower_median(size, v), dtype=torch.float64), 1))
    return _structure(hp, v, sigmas * scale, 6, size) if scale > 0 else v


def quiet_mask(depth: torch.Tensor, sigmas: float = 6.0, width: int = 15) -> torch.Tensor:
    """:func:`structure_mask` at ``sigmas`` robust standard deviations (``1.4826`` times the
    median absolute value over the valid pixels) of the row high-pass itself: the scale includes
    the noise *and* any stripes, so stripes far above the noise stay in the region and only scene
    structure (edges, thin objects: outliers of the high-pass) is left out. A threshold from the
    noise alone would leave out every pixel of a frame whose stripes are many noise sigmas."""
    _check(depth)
    v = valid_mask(depth)
    return _quiet(v, row_highpass(depth, width, v), sigmas)


@dataclass
class StripeEnergy:
    """Result of :func:`column_stripe_energy`, one entry per image (B * C,) unless noted.

    Attributes:
        covariance: ``E`` (depth units squared).
        correlation: the correlation coefficient of the two profiles.
        spread: the standard deviation of the mean profile ``(p_top + p_bot) / 2`` (counts noise).
        top, bottom: (B * C, W) profiles (NaN at columns not used).
        columns: (B * C,) number of columns used.
    """

    covariance: torch.Tensor
    correlation: torch.Tensor
    spread: torch.Tensor
    top: torch.Tensor
    bottom: torch.Tensor
    columns: torch.Tensor


def column_stripe_energy(
    depth: torch.Tensor,
    region: torch.Tensor | None = None,
    width: int = 9,
    split: int | None = None,
    min_rows: int = 16,
) -> StripeEnergy:
    """Column-stripe energy (module docstring) of every image of ``depth`` (B, C, H, W).

    Args:
        region: bool (B, C, H, W) pixels to use (default: the valid ones); invalid pixels never
            count.
        width: the high-pass width (odd int >= 3).
        split: first row of the bottom part (default ``H // 2``).
        min_rows: a column is used when it has at least this many region pixels in each part.
    """
    _check(depth)
    h = depth.shape[-2]
    s = h // 2 if split is None else int(split)
    if not 0 < s < h:
        raise ValueError(f"split must lie in (0, H = {h}), got {split!r}")
    v = valid_mask(depth)
    m = v if region is None else (region & v)
    return _energy(row_highpass(depth, width, v), m, s, min_rows)


def _energy(hp: torch.Tensor, m: torch.Tensor, s: int, min_rows: int) -> StripeEnergy:
    """:func:`column_stripe_energy` from the high-pass ``hp`` and the pixels ``m`` it uses (the
    region's valid ones), the bottom part from row ``s``."""
    b, c, h, w = hp.shape
    hp, m = hp.reshape(b * c, h, w), m.reshape(b * c, h, w)
    profiles, counts = [], []
    for rows in (slice(0, s), slice(s, h)):
        n = m[:, rows].sum(1).double()
        # the masked high-pass is exact in its own dtype; summed in float64
        part = torch.where(m[:, rows], hp[:, rows], 0.0).sum(1, dtype=torch.float64)
        profiles.append(part / n.clamp_min(1.0))
        counts.append(n)
    use = (counts[0] >= min_rows) & (counts[1] >= min_rows)
    k = use.sum(1).double()
    nan = torch.full_like(profiles[0], float("nan"))
    top, bot = (torch.where(use, p, nan) for p in profiles)
    mt = torch.where(use, top, 0.0).sum(1, keepdim=True) / k.clamp_min(1.0)[:, None]
    mb = torch.where(use, bot, 0.0).sum(1, keepdim=True) / k.clamp_min(1.0)[:, None]
    dt, db = torch.where(use, top - mt, 0.0), torch.where(use, bot - mb, 0.0)
    cov = (dt * db).sum(1) / k.clamp_min(1.0)
    vt, vb = (dt * dt).sum(1) / k.clamp_min(1.0), (db * db).sum(1) / k.clamp_min(1.0)
    corr = cov / torch.sqrt(vt * vb).clamp_min(1e-300)
    mean = 0.5 * (dt + db)
    spread = torch.sqrt((mean * mean).sum(1) / k.clamp_min(1.0))
    return StripeEnergy(cov, corr, spread, top, bot, k)


def lowpass_change(
    before: torch.Tensor, after: torch.Tensor, size: int = 15, region: torch.Tensor | None = None
) -> torch.Tensor:
    """RMS (per image) over the valid pixels of ``before`` (and ``region``) of ``after - before``
    averaged over ``size x size`` valid pixels."""
    _check(before, "before")
    _check(after, "after")
    if before.shape != after.shape:
        raise ValueError(
            f"before and after must have the same shape, got {list(before.shape)} and "
            f"{list(after.shape)}"
        )
    if isinstance(size, bool) or not isinstance(size, int) or size < 1:
        raise ValueError(f"size must be an int >= 1, got {size!r}")
    v = valid_mask(before)
    d = torch.where(v, after.double() - before.double(), 0.0)
    return _lowpass_rms(d, v, v if region is None else (region & v), size)


def _lowpass_rms(d: torch.Tensor, v: torch.Tensor, m: torch.Tensor, size: int) -> torch.Tensor:
    """:func:`lowpass_change` from the change ``d`` (float64, 0 where not ``v``), the valid pixels
    ``v`` and those of the RMS, ``m`` (a part of ``v``)."""
    b, c, h, w = d.shape
    d = d.reshape(b * c, h, w)
    vv = v.reshape(b * c, h, w).double()  # counts, exact
    lo, hi = size // 2, size - 1 - size // 2  # the window of a size x size mean, zero padded
    num = _window_sum(_window_sum(d, -1, lo, hi), -2, lo, hi)
    den = _window_sum(_window_sum(vv, -1, lo, hi), -2, lo, hi)
    mm = m.reshape(b * c, h, w)
    low = torch.where(mm, num / den, 0.0)  # den >= 1 at a valid pixel
    return torch.sqrt((low * low).sum((1, 2)) / mm.sum((1, 2)).clamp_min(1))


def energy_before_after(
    before: torch.Tensor,
    after: torch.Tensor,
    width: int = 9,
    min_rows: int = 16,
    *,
    valid: tuple[torch.Tensor, torch.Tensor] | None = None,
) -> tuple[StripeEnergy, StripeEnergy]:
    """The column-stripe energy of ``before`` and of ``after`` (same shape, (B, C, H, W), H >= 2)
    over the same region, the quiet pixels of ``before`` (:func:`quiet_mask`): what a correction
    did to the stripes. Equal to ``column_stripe_energy(x, quiet_mask(before), width)`` for both,
    at the cost of fewer filters (the high-passes of ``before`` share their cumulative sums).
    ``valid``: the valid pixels of ``before`` and ``after`` (``valid_mask`` of each), if known."""
    _check(before, "before")
    _check(after, "after")
    _check_width(width)
    if before.shape != after.shape:
        raise ValueError(
            f"before and after must have the same shape, got {list(before.shape)} and "
            f"{list(after.shape)}"
        )
    h = before.shape[-2]
    if h < 2:
        raise ValueError(f"the frames need two rows or more to split, got H = {h}")
    vb, va = (valid_mask(before), valid_mask(after)) if valid is None else valid
    counts = _counts(vb, (15, width))
    hq, hb = _highpasses(before, vb, (15, width), counts)
    quiet = _quiet(vb, hq, 6.0)
    if after is before:  # the same frame: measured once
        energy = _energy(hb, quiet, h // 2, min_rows)
        return energy, energy
    # the after's valid pixels are mostly the before's (a stage may invalidate some)
    (ha,) = _highpasses(after, va, (width,), counts if torch.equal(va, vb) else None)
    return _energy(hb, quiet, h // 2, min_rows), _energy(ha, quiet & va, h // 2, min_rows)
