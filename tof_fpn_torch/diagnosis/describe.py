"""Words and numbers for the report: where a statistic departs from its null (what a fitted
term's parameters mean in physical units is each term's ``describe``)."""

from __future__ import annotations

import math

import torch

from .. import constants as K
from .locate import Stat

__all__ = ["spectrum", "where"]

_UNITS = {
    "depth_mean": ("mm", 1e3),
    "amp_mean": ("%", 1e2),
    "depth_spread": ("x", 1.0),
    "amp_spread": ("x", 1.0),
    "depth_frame": ("mm", 1e3),
    "amp_frame": ("%", 1e2),
}


def spectrum(stat: Stat) -> dict:
    """Periodogram of a column / row profile of standardised means (null mean 1 per bin) and
    what it says: the strongest frequencies, the share of the excess power near ``2 pi / 3`` and
    ``pi``, how many bins hold half of it, and the verdict ``periodic`` / ``broadband``."""
    n = stat.n
    z = torch.where(n > 0, stat.zbar * torch.sqrt(n), torch.zeros_like(n))
    has = n > 0
    z = torch.where(has, z - z[has].mean(), z)
    length = z.numel()
    p = (torch.fft.rfft(z).abs() ** 2 / max(int(has.sum()), 1))[1:]
    freqs = torch.arange(1, p.numel() + 1, dtype=torch.float64) * (2 * math.pi / length)
    ex = (p - 1.0).clamp_min(0)
    total = float(ex.sum())
    bw = 1.5 * 2 * math.pi / length
    near = {}
    for name, w in (("2pi/3", K.FPN_FREQUENCIES[0]), ("pi", math.pi)):
        near[name] = float(ex[(freqs - w).abs() <= bw].sum()) / total if total > 0 else 0.0
    order = torch.argsort(ex, descending=True)
    cum = torch.cumsum(ex[order], 0)
    n50 = int((cum < 0.5 * total).sum()) + 1 if total > 0 else 0
    low = float(ex[freqs < math.pi / 4].sum()) / total if total > 0 else 0.0
    verdict = "broadband" if n50 > max(3, int(0.03 * p.numel())) else "periodic"
    return {
        "verdict": verdict,
        "bins_holding_half_the_excess_power": n50,
        "frequency_bins": int(p.numel()),
        "excess_power_share_near": near,
        "excess_power_share_below_pi/4": low,
        "strongest_rad_per_px": [
            {"frequency": round(float(freqs[i]), 4), "power_over_null": round(float(p[i]), 2)}
            for i in order[:5].tolist()
        ],
    }


def _ranges(stat: Stat, unit: str, scale: float) -> list[dict]:
    ax = stat.axis
    zs = stat.zbar * torch.sqrt(stat.n)
    hot = (zs.abs() > 3.0) & (stat.n > 0)
    out, i, nb = [], 0, zs.numel()
    edges = ax.edges if ax.edges else None
    while i < nb:
        if not bool(hot[i]):
            i += 1
            continue
        j = i
        while j + 1 < nb and bool(hot[j + 1]) and bool((zs[j + 1] > 0) == (zs[i] > 0)):
            j += 1
        lo = edges[i] if edges and i < len(edges) else float(ax.centres[i])
        hi = edges[j + 1] if edges and j + 1 < len(edges) else float(ax.centres[j])
        w = stat.n[i : j + 1]
        mean = float((stat.phys[i : j + 1] * w).sum() / w.sum())
        out.append(
            {
                "from": round(float(lo), 4),
                "to": round(float(hi), 4),
                "unit": ax.unit,
                "mean_residual": round(mean * scale, 4),
                "residual_unit": unit,
                "pixels": int(w.sum()),
            }
        )
        i = j + 1
    out.sort(key=lambda r: -abs(r["mean_residual"]))
    return out[:5]


def where(stat: Stat) -> dict:
    """Where a statistic departs: axis ranges (or frequencies, frames, counts) and sizes."""
    channel, axis = stat.key.split("|")
    out = {
        "statistic": stat.key,
        "value": round(stat.value, 3),
        "df": stat.df,
        "p": stat.p,
        "null_band_95": [round(x, 3) for x in stat.band()],
        "excess_sigma": round(stat.excess, 2),
    }
    unit, scale = _UNITS.get(channel, ("", 1.0))
    if stat.kind == "count":
        out["expected"] = round(stat._lam(), 2)
        return out
    if axis in ("column", "row"):
        w = stat.n.clamp_min(1e-12)
        prof = stat.phys[stat.n > 0]
        out["profile_rms"] = round(float(prof.std()) * scale, 4) if prof.numel() > 1 else 0.0
        out["profile_unit"] = unit
        out["spectrum"] = spectrum(stat)
        zs = stat.zbar * torch.sqrt(w)
        top = torch.argsort(zs.abs(), descending=True)[:5]
        out[f"strongest_{axis}s"] = [int(i) for i in top.tolist()]
        return out
    if axis == "pixels":
        zs = stat.zbar[stat.n > 0]
        out["share_beyond_4_sigma"] = round(float((zs.abs() > 4).double().mean()), 5)
        out["dispersion_ratio"] = round(math.sqrt(stat.value / max(stat.df, 1) / stat.scale), 4)
        return out
    if axis == "frame":
        zs = stat.zbar * torch.sqrt(stat.n)
        hot = (zs.abs() > 3).nonzero().squeeze(1).tolist()
        out["frames_beyond_3_sigma"] = hot[:20]
        out["frame_residual"] = [round(float(x) * scale, 4) for x in stat.phys.tolist()]
        out["residual_unit"] = unit
        return out
    out["ranges"] = _ranges(stat, unit, scale)
    return out
