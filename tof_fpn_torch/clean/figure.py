"""``OUTPUT/report.png``: the frame that cleaning changed most, before and after, so a user sees at
a glance what ``tof-fpn clean`` did.

The frame is the most changed of all the files written (the largest RMS change of stored output
less input; each file's record names its most changed measured frame, ``change_rms_mm`` and
``change_frame``, :mod:`.measure`, so only that one frame is read back, from INPUT and from
OUTPUT as stored). The panels:

* the input and the output depth (one colour scale, the 1st to 99th percentile of the input);
* the change, output less input (mm), on a symmetric scale at the change's own size: the 95th
  percentile of its magnitude over the changed pixels (:func:`difference_limit`), so a 1 mm
  change fills the bar at about 1 mm whatever the few outliers;
* the column profile and the row profile before and after (mm): the 9-pixel high-passed depth
  (:func:`~tof_fpn_torch.analysis.stripe_energy.row_highpass`, along the rows, resp. the
  columns) averaged down each column, resp. along each row, over the quiet pixels of the input
  (:func:`~tof_fpn_torch.analysis.quiet_mask`): a column stripe is a profile with a pattern that
  the cleaning should flatten;
* the power spectra of those profiles before and after, without frequency 0 (a profile's mean is
  no stripe): a stripe pattern is a raised spectrum (a line at ``2 pi / 3`` or ``pi`` for
  CamCube-like stripes, a broad floor for broadband offsets) that the cleaning should bring down
  to the noise floor;
* with ``pattern_mm``, a learned fixed pattern ((H, W), mm) as one more panel.
"""

from __future__ import annotations

import os

import numpy as np
import torch

from ..analysis.stripe_energy import quiet_mask, row_highpass
from ..io.stored import frame_set_tensors, read_frame_sets
from ..plotting import pyplot
from .config import CleanConfig
from .manifest import read_manifest
from .plan import MANIFEST, Job

__all__ = ["FIGURE_NAME", "difference_limit", "most_changed", "report_figure"]

#: the figure's name in OUTPUT
FIGURE_NAME = "report.png"
#: the percentile of the changed pixels' change magnitude at which its colour scale ends
DIFFERENCE_PERCENTILE = 95.0


def most_changed(jobs: list[Job], records: list[dict]) -> list[tuple[Job, str, int, float | None]]:
    """The candidates for the figure, most changed first: ``(job, set key, frame, RMS change in
    mm)`` for the jobs whose last manifest record is ``done``, by the record's
    ``change_rms_mm`` (its ``change_frame``); a record without them (not measured) comes last,
    at its first frame, in the order of ``jobs``."""
    last = {rec["file"]: rec for rec in records if "file" in rec}
    ranked = []
    for order, job in enumerate(jobs):
        rec = last.get(job.name)
        if rec is None or rec.get("status") != "done":
            continue
        report = rec.get("report") or {}
        rms, where = report.get("change_rms_mm"), report.get("change_frame")
        if isinstance(rms, (int, float)) and isinstance(where, dict):
            ranked.append((-float(rms), order, (job, where.get("set", ""), where["frame"], rms)))
        else:
            ranked.append((float("inf"), order, (job, "", 0, None)))
    return [c for *_, c in sorted(ranked, key=lambda r: (r[0], r[1]))]


def difference_limit(change_mm: torch.Tensor) -> float:
    """The end of the change panel's symmetric colour scale (mm): the
    :data:`DIFFERENCE_PERCENTILE` percentile of the change's magnitude over the pixels that
    changed (robust to a few outliers, at the scale of the change itself: a change of 1 mm gives
    about 1 mm, and a change of a few pixels is not drowned by the many unchanged); 1e-3 where
    nothing changed."""
    finite = change_mm[torch.isfinite(change_mm) & (change_mm != 0)].abs().double()
    if finite.numel() == 0:
        return 1e-3
    lim = float(np.percentile(finite.numpy(), DIFFERENCE_PERCENTILE))
    return lim if lim > 1e-3 else 1e-3


def _frame(path, partner, config: CleanConfig, scale, key: str, index: int) -> torch.Tensor:
    sets = read_frame_sets(
        path, partner, height=config.height, width=config.width, depth_scale=scale
    )
    fs = next((s for s in sets if s.key == key), None)
    if fs is None or not 0 <= index < fs.depth.shape[0]:
        raise ValueError(f"no frame {index} in set {key!r}")
    depth, _ = frame_set_tensors(fs, allow_empty=True)
    return depth[index : index + 1]


def _profiles(before: torch.Tensor, after: torch.Tensor, rows: bool):
    """The (mm) profiles of the 9-pixel high-passed depth over the input's quiet pixels, before
    and after: down each column (``rows`` False) or along each row; NaN where no pixel is
    quiet."""
    b, a = (before.mT, after.mT) if rows else (before, after)
    b, a = b.contiguous(), a.contiguous()
    quiet = quiet_mask(b)
    out = []
    for x in (b, a):
        use = quiet & torch.isfinite(x)
        hp = row_highpass(x, 9, use).double()
        n = use.sum(-2).double()
        p = torch.where(use, hp, 0.0).sum(-2) / n.clamp_min(1.0)
        out.append((1e3 * torch.where(n > 0, p, float("nan"))).flatten().numpy())
    return out


def _spectrum(profile: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(frequency in units of pi, power in mm^2) of a profile, frequency 0 left out."""
    p = np.where(np.isfinite(profile), profile, np.nan)
    p = np.nan_to_num(p - np.nanmean(p)) if np.isfinite(p).any() else np.zeros_like(p)
    power = np.abs(np.fft.rfft(p)) ** 2 / max(p.size, 1)
    freq = np.linspace(0.0, 1.0, power.size) if power.size > 1 else np.zeros(1)
    return freq[1:], power[1:]


def report_figure(
    output: str,
    jobs: list[Job],
    config: CleanConfig,
    pattern_mm=None,
    records: list[dict] | None = None,
) -> str | None:
    """Draw ``OUTPUT/report.png`` for the most changed frame of the done ``jobs`` (module
    docstring); returns its path, or None when there is nothing to show.

    Args:
        pattern_mm: a learned fixed pattern, (H, W) array-like in mm, drawn as an extra panel
            (none by default); or a dict file name -> pattern (each file's camera's).
        records: the run's manifest records (default: read from ``OUTPUT/manifest.jsonl``).
    """
    if records is None:
        records = read_manifest(os.path.join(output, MANIFEST))
    shown = None
    out_scale = config.output_scale or config.depth_scale
    candidates = most_changed(jobs, records)
    for job, key, index, _ in candidates:
        try:
            before = _frame(job.depth, job.amplitude, config, config.depth_scale, key, index)
            after = _frame(job.out_depth, job.out_amplitude, config, out_scale, key, index)
        except (OSError, ValueError):  # not written (failed) or not readable: the next one
            continue
        if before.shape == after.shape:
            shown = (job.name, key, index, before, after)
            break
    if shown is None:
        return None
    name, key, index, before, after = shown
    b, a = before[0, 0], after[0, 0]
    change = (a - b) * 1e3
    both = torch.isfinite(change)
    rms = float(change[both].square().mean().sqrt()) if bool(both.any()) else 0.0
    lim = difference_limit(change)

    plt = pyplot()
    if isinstance(pattern_mm, dict):  # one per camera: the shown file's
        pattern_mm = pattern_mm.get(name)
    pattern = None if pattern_mm is None else np.asarray(pattern_mm, dtype=np.float64)
    if pattern is not None and pattern.ndim != 2:
        raise ValueError(f"pattern_mm must be an (H, W) array, got shape {pattern.shape}")
    top = ["input", "output", "change"] + (["pattern"] if pattern is not None else [])
    bottom = ["columns", "rows", "spectra"] + (["spectra"] if pattern is not None else [])
    # fixed margins: the constrained layout's solver cost half the run's figure time
    fig, ax = plt.subplot_mosaic([top, bottom], figsize=(4.6 * len(top), 8.4))
    fig.subplots_adjust(left=0.05, right=0.98, top=0.88, bottom=0.08, wspace=0.28, hspace=0.42)
    where = f"{name}" + (f" [{key}]" if key else "") + f", frame {index}"
    fig.suptitle(
        f"{where}: the most changed of {len(candidates)} file(s), RMS change {rms:.3g} mm",
        fontsize=12,
    )
    ok = b[torch.isfinite(b)].double()
    if ok.numel():
        lo, hi = (float(q) for q in np.percentile(ok.numpy(), [1.0, 99.0]))
    else:
        lo, hi = 0.0, 1.0
    for panel, img, title in (("input", b, "input"), ("output", a, "output")):
        im = ax[panel].imshow(img.numpy(), vmin=lo, vmax=hi, cmap="viridis")
        ax[panel].set_title(f"{title} depth (m)", fontsize=10)
        fig.colorbar(im, ax=ax[panel], shrink=0.85)
    im = ax["change"].imshow(
        change.numpy(), cmap="RdBu_r", vmin=-lim, vmax=lim, interpolation="nearest"
    )
    ax["change"].set_title("output - input (mm)", fontsize=10)
    bar = fig.colorbar(im, ax=ax["change"], shrink=0.85)
    bar.set_label(f"to the {DIFFERENCE_PERCENTILE:g}th percentile of |change|", fontsize=8)
    if pattern is not None:
        finite = np.abs(pattern[np.isfinite(pattern)])
        plim = float(np.percentile(finite, DIFFERENCE_PERCENTILE)) if finite.size else 1.0
        plim = plim if plim > 1e-3 else 1e-3
        im = ax["pattern"].imshow(
            pattern, cmap="RdBu_r", vmin=-plim, vmax=plim, interpolation="nearest"
        )
        ax["pattern"].set_title("learned fixed pattern (mm)", fontsize=10)
        fig.colorbar(im, ax=ax["pattern"], shrink=0.85)
    for panel in top:
        ax[panel].set_xticks([])
        ax[panel].set_yticks([])
    spectra = ax["spectra"]
    for rows, panel, style in ((False, "columns", "-"), (True, "rows", ":")):
        profiles = _profiles(before, after, rows)
        along = "row" if rows else "column"
        for prof, colour, label in zip(
            profiles, ("tab:red", "tab:blue"), ("input", "output"), strict=True
        ):
            ax[panel].plot(np.arange(prof.size), prof, color=colour, lw=0.8, label=label)
            f, p = _spectrum(prof)
            if f.size:
                spectra.semilogy(
                    f, np.maximum(p, 1e-12), style, color=colour, lw=0.9, label=f"{label}, {panel}"
                )
        ax[panel].set_xlabel(along)
        ax[panel].set_ylabel("mm")
        how = "along each row" if rows else "down each column"
        ax[panel].set_title(f"{along} profile\n(high-passed depth, mean {how})", fontsize=10)
        ax[panel].legend(fontsize=8)
    for w in (2.0 / 3.0, 1.0):
        spectra.axvline(w, color="0.7", lw=0.8)
    spectra.set_xlabel("frequency (x pi rad / pixel; 0 left out)")
    spectra.set_ylabel("mm^2")
    spectra.set_title("power spectra of the profiles", fontsize=10)
    spectra.legend(fontsize=8)
    path = os.path.join(output, FIGURE_NAME)
    tmp = path + f".tmp{os.getpid()}.png"
    meta = {
        "Title": f"tof-fpn clean: {where}",
        "Description": (
            f"file={name}; set={key}; frame={index}; change_rms_mm={rms:.6g}; "
            f"change_limit_mm={lim:.6g}"
        ),
    }
    fig.savefig(tmp, dpi=80, metadata=meta)
    plt.close(fig)
    os.replace(tmp, path)
    return path
