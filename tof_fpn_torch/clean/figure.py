"""``OUTPUT/report.png``: a few cleaned frames before and after, so a user sees at a glance what
``tof-fpn clean`` did.

One row per file (the first :data:`FIGURE_FILES` files written by the run, their first frame, read
back from INPUT and from OUTPUT as stored): the input depth, the output depth (one colour scale),
the change (mm, symmetric scale), and the power spectra of the column and row profiles (the
9-pixel high-passed depth averaged down the columns / along the rows over the quiet pixels,
:func:`~tof_fpn_torch.analysis.quiet_mask`) before and after: a stripe pattern is a raised
spectrum (a line at ``2 pi / 3`` or ``pi`` for CamCube-like stripes, a broad floor for
broadband offsets) that the cleaning should bring down to the noise floor.
"""

from __future__ import annotations

import os

import torch

from ..analysis.stripe_energy import quiet_mask, row_highpass
from ..io.stored import frame_set_tensors, read_frame_sets
from ..plotting import pyplot
from .config import CleanConfig
from .plan import Job

__all__ = ["FIGURE_FILES", "FIGURE_NAME", "report_figure"]

#: files shown in the figure
FIGURE_FILES = 3
#: the figure's name in OUTPUT
FIGURE_NAME = "report.png"


def _first_frame(path, partner, config: CleanConfig, scale) -> torch.Tensor:
    sets = read_frame_sets(
        path, partner, height=config.height, width=config.width, depth_scale=scale
    )
    depth, _ = frame_set_tensors(sets[0], allow_empty=True)
    return depth[:1]


def _spectrum(depth: torch.Tensor, rows: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """(frequency in units of pi, power) of the quiet pixels' high-passed profile."""
    d = depth.mT if rows else depth
    quiet = quiet_mask(d)
    hp = row_highpass(d, 9, quiet)
    n = quiet.sum(-2).clamp_min(1).double()
    profile = (torch.where(quiet, hp, 0.0).sum(-2) / n).flatten().double()
    profile = profile - profile.mean()
    power = torch.fft.rfft(profile).abs() ** 2 / max(profile.numel(), 1)
    freq = torch.linspace(0.0, 1.0, power.numel())
    return freq, power


def report_figure(output: str, jobs: list[Job], config: CleanConfig) -> str | None:
    """Draw the figure for the first done ``jobs`` (at most :data:`FIGURE_FILES`); returns its
    path, or None when there is nothing to show."""
    shown = []
    for job in jobs:
        if len(shown) == FIGURE_FILES:
            break
        try:
            before = _first_frame(job.depth, job.amplitude, config, config.depth_scale)
            out_scale = config.output_scale or config.depth_scale
            after = _first_frame(job.out_depth, job.out_amplitude, config, out_scale)
        except (OSError, ValueError):  # not written (failed) or not readable: not shown
            continue
        if before.shape == after.shape:
            shown.append((job.name, before, after))
    if not shown:
        return None
    plt = pyplot()
    fig, axes = plt.subplots(len(shown), 4, figsize=(17, 3.8 * len(shown)), squeeze=False)
    for row, (name, before, after) in zip(axes, shown, strict=True):
        b, a = before[0, 0], after[0, 0]
        ok = b[torch.isfinite(b)]
        lo, hi = (float(ok.quantile(0.01)), float(ok.quantile(0.99))) if ok.numel() else (0, 1)
        for ax, img, title in ((row[0], b, "input"), (row[1], a, "output")):
            im = ax.imshow(img.numpy(), vmin=lo, vmax=hi, cmap="viridis")
            ax.set_title(f"{name}: {title} depth (m)", fontsize=9)
            fig.colorbar(im, ax=ax, fraction=0.046)
        change = (a - b) * 1e3
        finite = change[torch.isfinite(change)]
        lim = float(finite.abs().quantile(0.99)) if finite.numel() else 1.0
        im = row[2].imshow(change.numpy(), cmap="RdBu_r", vmin=-max(lim, 1e-3), vmax=max(lim, 1e-3))
        row[2].set_title("output - input (mm)", fontsize=9)
        fig.colorbar(im, ax=row[2], fraction=0.046)
        for rows, style in ((False, "-"), (True, ":")):
            for img, colour, label in ((before, "tab:red", "input"), (after, "tab:blue", "output")):
                f, p = _spectrum(img, rows)
                kind = "rows" if rows else "columns"
                row[3].semilogy(
                    f, p.clamp_min(1e-16), style, color=colour, label=f"{label}, {kind}"
                )
        for w in (2.0 / 3.0, 1.0):
            row[3].axvline(w, color="0.7", lw=0.8)
        row[3].set_xlabel("frequency (x pi rad / pixel)")
        row[3].set_title("profile power spectra (m^2)", fontsize=9)
        row[3].legend(fontsize=7)
    for ax in axes[:, :3].flat:
        ax.set_xticks([])
        ax.set_yticks([])
    fig.tight_layout()
    path = os.path.join(output, FIGURE_NAME)
    tmp = path + f".tmp{os.getpid()}.png"
    fig.savefig(tmp, dpi=80)
    plt.close(fig)
    os.replace(tmp, path)
    return path
