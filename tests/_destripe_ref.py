"""An independent NumPy / SciPy implementation of the destripe estimator (loops, no torch).

Written from the description in ``tof_fpn_torch/runtime/_destripe_core.py``, with other tools:
the truncated moments from ``scipy.stats``, the local linear fits by ``np.polyfit`` per window,
the window sums by explicit slices, the trimmed means and medians per column pair by loops.
Medians follow torch's convention (the lower of the two middle values), which the estimator uses.
Slow: for small inputs only.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

MAD_TO_SIGMA = 1.0 / stats.norm.ppf(0.75)


def lower_median(v: np.ndarray) -> float:
    v = np.sort(np.asarray(v, dtype=np.float64).ravel())
    return float(v[(v.size - 1) // 2]) if v.size else math.nan


def moment(k: int, clip: float) -> float:
    """E[|e|^2 | |e| <= clip] for |e| of k standard normal components (k = 1 or 2)."""
    if k == 1:
        return float(stats.truncnorm(-clip, clip).var())
    dist = stats.chi(2)
    num = dist.expect(lambda r: r * r, lb=0.0, ub=clip)
    return float(num / dist.cdf(clip))


def robust_scale(mags: np.ndarray, k: int, clip: float) -> float:
    med = lower_median(mags)
    start = med * MAD_TO_SIGMA if k == 1 else med / math.sqrt(2 * math.log(2))
    sigma = start if start > 0 else math.sqrt(np.mean(mags**2) / k) if mags.size else 0.0
    m = moment(k, clip)
    for _ in range(2):
        sel = mags[mags <= clip * sigma]
        sigma = math.sqrt((np.mean(sel**2) if sel.size else 0.0) / m)
    return sigma


def half_means(x: np.ndarray, v: np.ndarray, clip: float, sub: np.ndarray) -> np.ndarray:
    """x: (K, R, W), v: (R, W) bool, sub: the pilot's rows -> (K, W - 1) robust pair means."""
    k, r, w = x.shape
    g = x[:, :, 1:] - x[:, :, :-1]
    ok = v[:, 1:] & v[:, :-1]
    gs, oks = g[:, sub], ok[sub]
    pilot = np.zeros((k, w - 1))
    for c in range(w - 1):
        for ch in range(k):
            vals = gs[ch, oks[:, c], c]
            pilot[ch, c] = lower_median(vals) if vals.size else 0.0
    e = gs - pilot[:, None, :]
    mag = np.sqrt((e**2).sum(0))
    sigma = robust_scale(mag[oks], k, clip)
    for c in range(w - 1):  # trimmed mean of the subsample around the median
        sel = oks[:, c] & (mag[:, c] <= clip * sigma)
        if sel.any():
            pilot[:, c] = gs[:, sel, c].mean(1)
    out = np.zeros((k, w - 1))
    for c in range(w - 1):
        e = g[:, :, c] - pilot[:, c : c + 1]
        inl = ok[:, c] & (np.sqrt((e**2).sum(0)) <= clip * sigma)
        vals = np.where(inl[None, :], g[:, :, c], pilot[:, c : c + 1])
        out[:, c] = vals.sum(1) / r
    return out


def reject_steps(m: np.ndarray, clip: float, max_share: float) -> np.ndarray:
    k = m.shape[0]
    med = np.median(m, axis=1, keepdims=True)
    mag = np.sqrt(((m - med) ** 2).sum(0))
    t = np.median(mag)
    sigma = t * MAD_TO_SIGMA if k == 1 else t / stats.rayleigh.median()
    edge = (mag > clip * sigma) & (sigma > 0)
    if edge.mean() > max_share:  # a mode of the steps (periodic stripes), not edges
        return m
    return np.where(edge[None, :], med, m)


def highpass(p: np.ndarray, width: int) -> np.ndarray:
    """p minus its least-squares line over the clipped window [x - h, x + h], per sample."""
    h = width // 2
    n = p.shape[-1]
    out = np.empty_like(p)
    j = np.arange(n, dtype=np.float64)
    for x in range(n):
        lo, hi = max(0, x - h), min(n, x + h + 1)
        for ch in range(p.shape[0]):
            if hi - lo >= 2:
                slope, icpt = np.polyfit(j[lo:hi], p[ch, lo:hi], 1)
                out[ch, x] = p[ch, x] - (slope * x + icpt)
            else:
                out[ch, x] = 0.0
    return out


def band_widths(width: int) -> list[int]:
    out, w = [], width // 2
    while w >= 5:
        out.append(w)
        w //= 2
    return out


def band(p: np.ndarray, widths: list[int], i: int) -> np.ndarray:
    hi = p if i == 0 else highpass(p, widths[i - 1])
    lo = highpass(p, widths[i]) if i < len(widths) else np.zeros_like(p)
    return hi - lo


def window_sum(q: np.ndarray, window: int) -> np.ndarray:
    h, n = window // 2, q.shape[-1]
    return np.array([q[max(0, x - h) : min(n, x + h + 1)].sum() for x in range(n)])


def column_offsets(
    x: np.ndarray,
    valid: np.ndarray | None,
    width: int,
    clip: float,
    shrink: str,
    local_width: int,
    pilot_rows: int,
    step_clip: float,
    null_z: float,
    max_share: float,
) -> np.ndarray:
    """x: (K, H, W) float64, valid: (H, W) bool or None -> offsets (K, W)."""
    k, h, w = x.shape
    v = np.ones((h, w), bool) if valid is None else valid
    half = h // 2
    rows = max(1, pilot_rows // 2)
    step = max(1, -(-(h - half) // rows))  # the same step in both halves, equally many rows
    sub = np.arange(min(-(-half // step), -(-(h - half) // step))) * step
    m_top = reject_steps(half_means(x[:, :half], v[:half], clip, sub), step_clip, max_share)
    m_bot = reject_steps(half_means(x[:, half:], v[half:], clip, sub), step_clip, max_share)
    width = max(3, min(width, w // 4))

    def profile(m):
        return highpass(np.concatenate([np.zeros((k, 1)), np.cumsum(m, 1)], 1), width)

    p_top, p_bot = profile(m_top), profile(m_bot)
    if k == 2:  # coherent projection: drop the part along the column phasor, times kappa^2
        s = x.sum(1)  # (2, W)
        norm = np.hypot(s[0], s[1])
        u = np.where(norm > 0, s / np.maximum(norm, 1e-30), 0.0)
        total = np.hypot(x[0], x[1]).sum(0)
        kappa = np.where(total > 0, norm / np.maximum(total, 1e-30), 0.0)
        p_top = p_top - kappa**2 * (p_top * u).sum(0) * u
        p_bot = p_bot - kappa**2 * (p_bot * u).sum(0) * u
    p_all = (half * p_top + (h - half) * p_bot) / h
    count = v.sum(0).astype(np.float64)
    if shrink == "none":
        out = p_all
    else:
        out = np.zeros_like(p_all)
        widths = band_widths(width)
        for i in range(len(widths) + 1):
            a, b, c = band(p_top, widths, i), band(p_bot, widths, i), band(p_all, widths, i)
            cross, energy = (a * b).sum(0), (c * c).sum(0)
            null = (((a - b) ** 2).sum(0) / 2) ** 2 / 3
            if shrink == "local":
                cross, energy, null = (window_sum(t, local_width) for t in (cross, energy, null))
            else:
                cross, energy, null = cross.sum(), energy.sum(), null.sum()
            f = np.where(
                energy > 0, (cross - null_z * np.sqrt(null)) / np.maximum(energy, 1e-300), 0
            )
            out += np.clip(f, 0, 1) * c
    return out - (out * count).sum(1, keepdims=True) / max(count.sum(), 1.0)
