"""Words and numbers for the report: where a statistic departs from its null, and what a fitted
term's parameters mean in physical units."""

from __future__ import annotations

import math
from dataclasses import replace

import torch

from .. import constants as K
from ..sim import Camera, SimState, depth_from_samples
from .catalogue import build_term
from .locate import Stat
from .model import peak_samples, predict

__all__ = ["describe_effect", "spectrum", "where"]

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


def cyclic_peak_to_peak(term, camera: Camera, points: int = 256) -> float:
    """Peak-to-peak depth error (m) of a :class:`~tof_fpn_torch.sim.CyclicError` over a range."""
    n = camera.n_phases
    phi = torch.linspace(0, 2 * math.pi, points + 1, dtype=torch.float64)[:-1].view(1, 1, 1, -1)
    th = torch.arange(n, dtype=torch.float64).view(1, n, 1, 1) * (2 * math.pi / n)
    s = 2.0 + torch.cos(phi + th)
    st = SimState(camera, None, s, None)
    out = term.apply(st).samples
    d, _, _ = depth_from_samples(out, float(camera.modulation_frequency))
    r = K.SPEED_OF_LIGHT_AIR / (2 * float(camera.modulation_frequency))
    err = d[0, 0, 0] - phi[0, 0, 0] * r / (2 * math.pi)
    err = err - r * torch.round(err / r)
    return float(err.max() - err.min())


def describe_effect(name: str, model, obs, pred) -> dict:
    """The fitted parameters of ``name`` in physical units (and a few derived numbers)."""
    v = model.values
    g = v["camera.conversion_gain"]
    r4 = lambda x: round(float(x), 4)  # noqa: E731
    if name == "cyclic_error":
        term = build_term(name, v, model, for_chain=True)
        f = float(model.camera.modulation_frequency)
        return {
            "peak_to_peak_mm": r4(cyclic_peak_to_peak(term, model.camera) * 1e3),
            "period_m": r4(K.SPEED_OF_LIGHT_AIR / (2 * f * model.camera.n_phases)),
            "harmonics": list(term.harmonics),
            "cos_terms": [r4(x) for x in term.cos_terms],
            "sin_terms": [r4(x) for x in term.sin_terms],
        }
    if name == "amplitude_bias":
        a = pred.a0[obs.known]
        ref = v["amplitude_bias.reference"]
        lo, hi = (float(torch.quantile(a, q)) * g for q in (0.1, 0.9))
        b = v["amplitude_bias.delay"]
        return {
            "delay_mm": r4(b * 1e3),
            "reference_e": r4(ref),
            "reference_amplitude": r4(ref / g),
            "bias_at_p10_amplitude_mm": r4(b * ref / (lo + ref) * 1e3),
            "bias_at_p90_amplitude_mm": r4(b * ref / (hi + ref) * 1e3),
        }
    if name == "fpn_pattern":
        out = {
            "rms_columns_mm": r4(v.get("fpn_pattern.rms_columns", 0.0) * 1e3),
            "rms_rows_mm": r4(v.get("fpn_pattern.rms_rows", 0.0) * 1e3),
            "effective_parameters": r4(v.get("fpn_pattern.dof", 0.0)),
        }
        c = model.profiles.get("columns")
        if c is not None and c.numel() > 8:
            pw = torch.fft.rfft(c - c.mean()).abs()[1:] ** 2
            f = torch.arange(1, pw.numel() + 1, dtype=torch.float64) * (2 * math.pi / c.numel())
            tot = float(pw.sum()) or 1.0
            bw = 1.5 * 2 * math.pi / c.numel()
            out["profile_power_share_near_2pi/3"] = r4(
                float(pw[(f - K.FPN_FREQUENCIES[0]).abs() <= bw].sum()) / tot
            )
            out["profile_power_share_near_pi"] = r4(
                float(pw[(f - math.pi).abs() <= bw].sum()) / tot
            )
            out["white_share_of_those_bins"] = r4(
                float(
                    ((f - K.FPN_FREQUENCIES[0]).abs() <= bw).sum()
                    + ((f - math.pi).abs() <= bw).sum()
                )
                / pw.numel()
            )
        return out
    if name == "vignetting":
        vt = build_term(name, v, model, for_chain=True)
        h, w = obs.shape
        gain = vt.gain(h, w, pred.a0)[0, 0]
        return {
            "quadratic": r4(v["vignetting.quadratic"]),
            "quartic": r4(v["vignetting.quartic"]),
            "centre_px": [r4(v["vignetting.centre_x"]), r4(v["vignetting.centre_y"])],
            "corner_relative_illumination_percent": r4(
                100 * float(gain[[0, 0, -1, -1], [0, -1, 0, -1]].mean()) / float(gain.max())
            ),
        }
    if name == "temporal_drift":
        return {
            "depth_step_mm": r4(v["temporal_drift.depth_step"] * 1e3),
            "amplitude_step_percent": r4(v["temporal_drift.amplitude_step"] * 100),
            "time_constant": r4(v["temporal_drift.time_constant"]),
            "time_unit": "s" if model.frame_interval != 1.0 else "frames (or s)",
        }
    if name == "noise_floor":
        return {"sigma_mm": r4(v["noise_floor.sigma"] * 1e3)}
    if name == "pixel_gain":
        return {"rms_percent": r4(v["pixel_gain.rms"] * 100)}
    if name == "impulsive_pixels":
        return {"rate_percent": r4(v["impulsive_pixels.rate"] * 100)}
    if name == "saturation":
        lv = v["saturation.level"]
        # the largest raw sample the model predicts without the clip
        with torch.no_grad():
            p0 = predict(model.without("saturation"), obs)
        peak = peak_samples(model, p0, p0.mu_d, p0.a0)[obs.known] * g
        # the chance that a pixel's largest sample, with its shot and read noise, is clipped in
        # a frame, averaged over the pixels
        sd = torch.sqrt(peak.clamp_min(0) + v["camera.read_noise"] ** 2)
        clipped = torch.special.ndtr((peak - lv) / sd)
        return {
            "level_e": r4(lv),
            "level_amplitude_units": r4(lv / g),
            "share_of_pixels_clipped": r4(float(clipped.double().mean())),
        }
    if name == "multipath":
        return _describe_multipath(model, obs, v, r4)
    if name == "flying_pixels":
        return {"psf_sigma_px": r4(v["flying_pixels.sigma"])}
    if name == "phase_wrapping":
        rng = v["phase_wrapping.range"]
        return {
            "range_m": r4(rng),
            "modulation_frequency_mhz": r4(K.SPEED_OF_LIGHT_AIR / (2 * rng) / 1e6),
            "share_of_pixels_beyond": r4(
                float((obs.scene_depth[obs.known] >= rng).double().mean())
            ),
        }
    return {}


def _describe_multipath(model, obs, v: dict, r4) -> dict:
    """Relayed / direct active light of every pixel (offsets: no phasor cancellation)."""
    from ..sim import Photons

    cam = replace(model.camera, ambient_irradiance=0.0)
    scene = obs.scene()
    with torch.no_grad():
        act = Photons(responsivity=1.0).mean_samples(cam, scene).to(torch.float64)
        term = build_term("multipath", v, model, for_chain=True)
        direct = act.mean(1)[0]
        rho = scene.reflectance[0, 0].to(torch.float64)
        uniform = v["multipath.strength"] * (rho / rho.mean()) * direct.mean()
        geo = v.get("multipath.scene_relay", 0.0)
        inner = geo * term.relayed(act, SimState(cam, scene, act, None)).mean(1)[0]
    ratio = (uniform + inner) / direct
    return {
        "strength_percent": r4(v["multipath.strength"] * 100),
        "extra_path_m": r4(v["multipath.extra_path"]),
        "scene_relay_efficiency_percent": r4(geo * 100),
        "field_of_view_deg": r4(v.get("multipath.field_of_view", K.MULTIPATH_FIELD_OF_VIEW_DEG)),
        "near_field_m": r4(v.get("multipath.near_field", K.MULTIPATH_NEAR_FIELD_M)),
        "median_relay_to_direct": r4(float(ratio[obs.known].median())),
        "median_scene_relay_to_direct": r4(float((inner / direct)[obs.known].median())),
    }
