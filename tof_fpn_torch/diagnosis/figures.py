"""Figures of a diagnosis, rendered in memory (PNG bytes): the residual along each located axis
before / after with the null band, the column-profile spectra, and sigma_D against A."""

from __future__ import annotations

import io
import math

import torch

from .. import constants as K
from ..plotting import pyplot
from .prediction import predict

__all__ = ["FIGURE_DPI", "figures"]

#: Resolution of the diagnosis figures.
FIGURE_DPI: int = 110

_LABEL = {
    "depth_mean": ("depth residual of the temporal mean", "mm", 1e3),
    "amp_mean": ("relative amplitude residual", "%", 1e2),
    "depth_spread": ("depth temporal sd / model", "", 1.0),
    "amp_spread": ("amplitude temporal sd / model", "", 1.0),
    "depth_frame": ("depth residual of the frame", "mm", 1e3),
    "amp_frame": ("relative amplitude residual of the frame", "%", 1e2),
}


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=FIGURE_DPI, bbox_inches="tight")
    pyplot().close(fig)
    return buf.getvalue()


def _axis_panel(ax, key: str, before, after) -> None:
    channel, axis = key.split("|")
    label, unit, scale = _LABEL.get(channel, (channel, "", 1.0))
    ref = 1.0 if channel.endswith("spread") else 0.0
    for stat, name, style in ((before, "before", "o-"), (after, "after", "s-")):
        if stat is None or stat.n is None:
            continue
        has = stat.n > 0
        x = stat.axis.centres[has] if stat.axis.centres.numel() == has.numel() else None
        if x is None:
            x = torch.arange(int(has.sum()), dtype=torch.float64)
        y = stat.phys[has] * scale
        ax.plot(x.tolist(), y.tolist(), style, ms=3, lw=1, label=f"{name} (p = {stat.p:.2g})")
        if stat.se2 is not None and name == "after":
            half = 1.96 * torch.sqrt(stat.scale * stat.se2[has] / stat.n[has]) * scale
            if channel.endswith("spread"):  # the sd ratio of n frames: ~ 1 / sqrt(2 (n - 1))
                half = torch.full_like(
                    y, 1.96 * math.sqrt(stat.scale / max(float(stat.n.mean()), 1))
                )
            ax.fill_between(
                x.tolist(),
                (ref * scale - half).tolist(),
                (ref * scale + half).tolist(),
                color="0.8",
                label="95 % null band",
            )
    ax.axhline(ref * scale, color="k", lw=0.5)
    ax.set_xlabel(f"{axis} ({stat.axis.unit})" if stat.axis.unit else axis)
    ax.set_ylabel(f"{label} ({unit})" if unit else label)
    ax.set_title(key, fontsize=9)
    ax.legend(fontsize=7)


def _spectrum(stat):
    n = stat.n
    z = torch.where(n > 0, stat.zbar * torch.sqrt(n), torch.zeros_like(n))
    has = n > 0
    z = torch.where(has, z - z[has].mean(), z)
    p = (torch.fft.rfft(z).abs() ** 2 / max(int(has.sum()), 1))[1:] / stat.scale
    f = torch.arange(1, p.numel() + 1, dtype=torch.float64) * (2 * math.pi / z.numel())
    return f, p


def figures(diag) -> dict[str, bytes]:
    """``{file name: PNG bytes}`` for a :class:`~tof_fpn_torch.diagnosis.Diagnosis`."""
    plt = pyplot()
    out = {}
    keys = []
    for e in diag.report["effects"]:
        for w in e["where"][:2]:
            if w["statistic"] not in keys and diag.before[w["statistic"]].n is not None:
                keys.append(w["statistic"])
    for w in diag.report["located_before"][:3]:
        s = w["statistic"]
        if s not in keys and diag.before[s].n is not None and not s.endswith("|pixels"):
            keys.append(s)
    keys = [k for k in keys if not k.endswith("|pixels")][:4] or ["depth_mean|column"]
    fig, axs = plt.subplots(len(keys), 1, figsize=(7, 2.6 * len(keys)), squeeze=False)
    for ax, k in zip(axs[:, 0], keys, strict=True):
        _axis_panel(ax, k, diag.before.get(k), diag.after.get(k))
    fig.tight_layout()
    out["residual_axes.png"] = _png(fig)

    fig, axs = plt.subplots(1, 2, figsize=(10, 3.2))
    for ax, key in zip(axs, ("depth_mean|column", "depth_mean|row"), strict=True):
        for stat, name in ((diag.before.get(key), "before"), (diag.after.get(key), "after")):
            if stat is None or stat.n is None:
                continue
            f, p = _spectrum(stat)
            ax.semilogy(f.tolist(), p.clamp_min(1e-3).tolist(), lw=0.8, label=name)
        ax.axhline(1.0, color="k", lw=0.5, label="null mean")
        ax.axhline(
            -math.log(0.01 / max(len(f), 1)),
            color="r",
            lw=0.5,
            ls="--",
            label="1 % max-of-bins level",
        )
        for w in K.FPN_FREQUENCIES:
            ax.axvline(w, color="0.5", lw=0.5, ls=":")
        ax.set_xlabel("frequency (rad / px)")
        ax.set_ylabel("power / null")
        ax.set_title(f"{key.split('|')[1]} profile of the depth residual", fontsize=9)
        ax.legend(fontsize=7)
    fig.tight_layout()
    out["profile_spectra.png"] = _png(fig)

    obs, ctx = diag.obs, diag.ctx
    fig, ax = plt.subplots(figsize=(6, 4))
    with torch.no_grad():
        pb = predict(diag.baseline, obs, scene=ctx.scene)
        pa = predict(diag.model, obs, scene=ctx.scene)
    m = ctx.mask_d
    a = pb.a0[m]
    edges = torch.quantile(a, torch.linspace(0, 1, 16, dtype=torch.float64)).unique()
    lab = torch.bucketize(a, edges[1:-1].contiguous())
    if obs.frames >= 2:
        meas = torch.sqrt(obs.m2_d / (obs.n - 1).clamp_min(1))[m]
        what = "temporal sd of depth"
    else:
        meas = (obs.m_d - pa.mu_d).abs()[m] * K.MAD_TO_SIGMA
        what = "1.48 |residual| (one frame)"
    xs, ys, yb, ya = [], [], [], []
    for b in range(edges.numel() - 1):
        sel = lab == b
        if int(sel.sum()) < 5:
            continue
        xs.append(float(a[sel].median()))
        ys.append(float(meas[sel].median()) * 1e3)
        yb.append(float(pb.sd_d[m][sel].median()) * 1e3)
        ya.append(float(pa.sd_d[m][sel].median()) * 1e3)
    ax.loglog(xs, ys, "ko", ms=4, label=f"measured ({what}, median)")
    ax.loglog(xs, yb, "b--", label="baseline model")
    ax.loglog(xs, ya, "r-", label="diagnosed model")
    ax.set_xlabel(f"amplitude A ({obs.amplitude_unit})")
    ax.set_ylabel("sigma_D (mm)")
    ax.legend(fontsize=7)
    ax.set_title("depth noise against amplitude", fontsize=9)
    fig.tight_layout()
    out["sigma_vs_amplitude.png"] = _png(fig)
    return out
