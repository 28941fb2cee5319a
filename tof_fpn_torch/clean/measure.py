"""What cleaning did to a file, measured on what was written: the record of ``tof-fpn clean``.

Per file (its frames, up to :data:`REPORT_FRAMES` evenly spaced per frame set, as decoded from the
input and from the output *as stored*, so integer rounding counts):

* ``stripes``: for columns and rows, the stripe energy before and after (mm^2; the covariance of
  the two halves' 9-pixel high-passed profiles over the quiet pixels,
  :func:`~tof_fpn_torch.analysis.column_stripe_energy` with
  :func:`~tof_fpn_torch.analysis.quiet_mask`: noise does not count, scene edges are left out) and
  the significance ``z = r sqrt(n)`` of the input's pattern (the halves' profiles' correlation
  ``r`` over ``n`` columns; a common pattern, i.e. a stripe, from 4 on);
* ``noise_mm``: the per-pixel noise (wavelet MAD, :func:`~tof_fpn_torch.denoise.estimate_sigma`);
* ``found``: whether a stripe pattern is in the input: ``z`` >= :data:`STRIPE_Z` and an amplitude
  ``sqrt(E)`` of at least the gate's floor (``GATE_MIN_STRIPE`` times the noise);
* ``gate``: the notch stage's per-frame gate (mean, and how many frames it opened for), where
  there is a notch;
* ``lowpass_change_mm``: the largest RMS change of the 15 x 15 low-passed depth
  (:func:`~tof_fpn_torch.analysis.lowpass_change`) over the pixels valid in both input and
  output (a stage may invalidate pixels): how far the scene itself moved;
* ``change_rms_mm``: the largest RMS change (stored output less input, over the pixels valid in
  both) of a measured frame, and ``change_frame``, that frame (``{"set": key, "frame": index}``,
  the index in its frame set): the frame ``OUTPUT/report.png`` shows (:mod:`.figure`);
* ``changed``: the share of valid pixels whose stored value changed;
* ``flying``: with the flying-pixel stage, the pixels it flagged and the valid pixels it saw, over
  all frames (``flagged``, ``valid``, ``share``), None without it.

A value that is undefined (no valid pixel to measure on; the stripe measure of a frame one pixel
wide or high, :func:`too_thin`) is None, JSON ``null``: the record never holds NaN
(:func:`finite_values`). :func:`summarise` condenses the records of a run into the lines the
command prints.
"""

from __future__ import annotations

import math
import statistics

import numpy as np
import torch

from .. import constants as K
from ..analysis.stripe_energy import _lowpass_rms, energy_before_after
from ..io.stored import FrameSet, frame_set_tensors
from ..runtime import valid_mask
from .steps import steps

__all__ = ["REPORT_FRAMES", "STRIPE_Z", "file_report", "finite_values", "summarise", "too_thin"]

#: frames measured per frame set (evenly spaced)
REPORT_FRAMES = 16
#: a stripe pattern is "found" from this significance of the halves' correlation
STRIPE_Z = 4.0
_ORIENTATIONS = {"columns": False, "rows": True}
MIN_STRIPE = K.GATE_MIN_STRIPE
_ENERGY_KEYS = ("before_mm2", "after_mm2", "z")


def too_thin(shape) -> bool:
    """Whether frames of ``shape`` (``(..., H, W)``) are one pixel wide or high: nothing to
    measure a stripe on (it needs two halves and a neighbourhood), and no stage of ``tof-fpn
    clean`` runs on them (they are copied as they are)."""
    return min(int(shape[-2]), int(shape[-1])) < 2


def finite_values(value):
    """``value`` (dicts, lists, numbers) with every NaN or infinite float replaced by None, so
    that it is valid JSON (``null`` where a measure is undefined)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: finite_values(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_values(v) for v in value]
    return value


def _energy(before: torch.Tensor, after: torch.Tensor, valid: tuple) -> dict:
    """Stripe energy before / after (mm^2) and the input pattern's significance, per orientation
    (None where the frame has fewer than two rows to split, resp. columns); ``valid``: the valid
    pixels of ``before`` and ``after``."""
    out = {}
    for name, transpose in _ORIENTATIONS.items():
        if too_thin(before.shape):
            out[name] = dict.fromkeys(_ENERGY_KEYS)
            continue
        # the profiles along contiguous lines; the before's quiet mask serves both
        b, a, vb, va = ((x.mT if transpose else x).contiguous() for x in (before, after, *valid))
        if after is before:
            a, va = b, vb  # unchanged: measured once
        eb, ea = energy_before_after(b, a, valid=(vb, va))
        n = float(eb.columns[0])
        r = float(eb.correlation[0])
        out[name] = {
            "before_mm2": 1e6 * float(eb.covariance[0]),
            "after_mm2": 1e6 * float(ea.covariance[0]),
            "z": r * math.sqrt(n) if n > 0 and math.isfinite(r) else 0.0,
        }
    return out


def _noise(x: torch.Tensor, valid: torch.Tensor) -> float:
    """:func:`~tof_fpn_torch.denoise.estimate_sigma` of one CPU frame ``x`` ((1, 1, H, W)
    float64, 0 where not ``valid``), the same wavelet MAD by a cheaper road (equal up to float
    rounding): the db2 diagonal detail as two 1-D filters of stride 2 (the kernel is an outer
    product), the 4 x 4 supports' invalid pixels counted the same way, the median by selection
    instead of a sort."""
    h, w = x.shape[-2:]
    if h < 4 or w < 4:
        return 0.0
    g = torch.tensor(K.DB2_DEC_HI, dtype=x.dtype).flip(0).tolist()
    ho, wo = (h - 4) // 2 + 1, (w - 4) // 2 + 1

    def cols(t, j):  # every second column from j, wo of them
        return t[..., j : j + 2 * wo - 1 : 2]

    def rows(t, i):
        return t[..., i : i + 2 * ho - 1 : 2, :]

    r = g[0] * cols(x, 0) + g[1] * cols(x, 1) + g[2] * cols(x, 2) + g[3] * cols(x, 3)
    d = g[0] * rows(r, 0) + g[1] * rows(r, 1) + g[2] * rows(r, 2) + g[3] * rows(r, 3)
    bad = (~valid).to(torch.uint8)
    c = cols(bad, 0) + cols(bad, 1) + cols(bad, 2) + cols(bad, 3)
    touched = rows(c, 0) + rows(c, 1) + rows(c, 2) + rows(c, 3)
    keep = (touched == 0) & (d != 0)
    n = int(keep.sum())
    if n == 0:
        return 0.0
    a = torch.where(keep, d.abs(), float("inf")).reshape(-1).numpy()  # the others sort last
    lo, hi = (n - 1) // 2, n // 2
    part = np.partition(a, (lo, hi))
    return float(0.5 * (part[lo] + part[hi]) * K.MAD_TO_SIGMA)


def _frame(before: torch.Tensor, after: torch.Tensor) -> dict:
    """The measures of one frame; ``after is before`` for a frame stored unchanged (its after
    measures are its before measures, not computed twice)."""
    valid = valid_mask(before)
    x = torch.where(valid, before, 0.0).double()
    noise = None
    if bool(valid.any()) and not too_thin(before.shape):
        noise = 1e3 * _noise(x, valid)
    valid_after = valid if after is before else valid_mask(after)
    both = valid & valid_after  # a stage may invalidate pixels (--flying invalidate)
    moved = rms = None
    if after is before and bool(both.any()):
        moved = rms = 0.0
    elif bool(both.any()):  # lowpass_change over the pixels valid in both
        d = torch.where(both, after.double() - before.double(), 0.0)
        moved = 1e3 * float(_lowpass_rms(d, both, both, 15))
        rms = 1e3 * math.sqrt(float((d * d).sum()) / int(both.sum()))
    return {
        "noise_mm": noise,
        "change_rms_mm": rms,
        "stripes": _energy(before, after, (valid, valid_after)),
        "lowpass_change_mm": moved,
        # a valid input pixel whose stored value changed (or became invalid)
        "changed": float(((before != after) & valid).sum()) / max(int(valid.sum()), 1),
    }


def _finite(values: list) -> list[float]:
    return [x for x in values if x is not None and math.isfinite(x)]


def _finite_mean(values: list) -> float | None:
    v = _finite(values)
    return sum(v) / len(v) if v else None


def file_report(sets: list[FrameSet], encoded: dict, output_scale: float | None = None) -> dict:
    """The record of one file (module docstring) from its frame sets as read and the encoded
    depth arrays (by set key; ``output_scale``: metres per unit of an integer output, None: the
    input's, as :func:`~tof_fpn_torch.io.encode.encode_depth`); the steps add their own entries
    (``gate``, ``flying``, ...)."""
    frames, where = [], []
    for fs in sets:
        t = int(fs.depth.shape[0])
        picks = sorted(
            {round(i * (t - 1) / max(REPORT_FRAMES - 1, 1)) for i in range(REPORT_FRAMES)}
        )
        picks = [i for i in picks if i < t]
        # only the measured frames are decoded
        integer = fs.depth.dtype.kind in "ui"
        scale = output_scale if integer and output_scale is not None else fs.depth_scale
        ins = FrameSet(fs.key, fs.depth[picks], fs.amplitude[picks], fs.depth_scale, fs.shape)
        out = FrameSet(fs.key, encoded[fs.key][picks], ins.amplitude, scale, fs.shape)
        before, _ = frame_set_tensors(ins, allow_empty=True)
        after, _ = frame_set_tensors(out, allow_empty=True)
        for j, i in enumerate(picks):
            b = before[j : j + 1]
            unchanged = scale == fs.depth_scale and np.array_equal(fs.depth[i], encoded[fs.key][i])
            frames.append(_frame(b, b if unchanged else after[j : j + 1]))
        where += [{"set": fs.key, "frame": i} for i in picks]
    stripes = {}
    for name in _ORIENTATIONS:
        stripes[name] = {
            k: _finite_mean([f["stripes"][name][k] for f in frames]) for k in _ENERGY_KEYS
        }
    noise = _finite_mean([f["noise_mm"] for f in frames])
    found = any(_found(s, noise) for s in stripes.values())
    rec = {
        "found": found,
        "noise_mm": noise,
        "stripes": stripes,
        "lowpass_change_mm": max(_finite([f["lowpass_change_mm"] for f in frames]), default=None),
        "change_rms_mm": None,
        "change_frame": None,
        "changed": _finite_mean([f["changed"] for f in frames]) or 0.0,
        "measured_frames": len(frames),
    }
    changes = [(f["change_rms_mm"], k) for k, f in enumerate(frames)]
    changes = [(c, k) for c, k in changes if c is not None and math.isfinite(c)]
    if changes:  # the most changed measured frame (the first of equals)
        rms, k = max(changes, key=lambda ck: (ck[0], -ck[1]))
        rec["change_rms_mm"], rec["change_frame"] = rms, where[k]
    return finite_values(rec)


def _found(s: dict, noise_mm: float) -> bool:
    """A significant pattern (``z >= STRIPE_Z``) of at least the gate's floor in amplitude
    (``sqrt(E) >= GATE_MIN_STRIPE`` times the per-pixel noise)."""
    energy = s["before_mm2"] or 0.0
    floor = (MIN_STRIPE * (noise_mm or 0.0)) ** 2
    return (s["z"] or 0.0) >= STRIPE_Z and energy > 0 and energy >= floor


def _db(before: float | None, after: float | None) -> float | None:
    if before is None or after is None or before <= 0:
        return None
    return 10.0 * math.log10(before / max(after, before * 1e-6))


def summarise(records: list[dict], stages_off: bool = False) -> list[str]:
    """Lines for the terminal from the ``done`` records of a run (``stages_off``: the run had no
    stage at all, every one switched off). One story: a file whose input has a stripe pattern
    (``found``) but whose depth was not changed is said to be left as it was, and why."""
    done = [r for r in records if r.get("status") == "done"]
    lines = []
    thin = [r for r in done if r.get("note")]
    if thin:
        lines.append(
            f"copied {len(thin)} file(s) with frames one pixel wide or high as they were (no "
            "stage works on them; the note in their manifest record)"
        )
    unmeasured = [r for r in done if r.get("report") and "error" in r["report"]]
    if unmeasured:
        lines.append(
            f"{len(unmeasured)} file(s) written but not measured (the reason is in their "
            "manifest record)"
        )
    reps = [r["report"] for r in done if r.get("report") and "error" not in r["report"]]
    if not reps:
        return lines
    changed = sum(r["changed"] > 0 for r in reps)
    found = [r for r in reps if r["found"]]
    acted = [r for r in found if r["changed"] > 0]
    left = [r for r in found if r["changed"] == 0]
    why = (
        "every stage is off"
        if stages_off
        else "the stage found nothing it could remove with confidence"
    )
    common = f"common to both halves of the frame, z >= {STRIPE_Z:g}"
    if found and not acted:
        lines += [
            f"changed {changed} of {len(reps)} file(s)",
            f"{why}; the record's stripe measure sees a pattern in {len(left)} file(s) "
            f"({common}): left as they were",
        ]
    else:
        lines.append(
            f"changed {changed} of {len(reps)} file(s); stripes found in {len(found)} "
            f"(a pattern {common})"
        )
        if left:
            lines.append(
                f"{len(left)} of them left as they were: the stage found nothing there it could "
                "remove with confidence"
            )
    for name in _ORIENTATIONS:
        gains = [
            _db(r["stripes"][name]["before_mm2"], r["stripes"][name]["after_mm2"])
            for r in acted
            if _found(r["stripes"][name], r["noise_mm"])
        ]
        gains = [g for g in gains if g is not None]
        if gains:
            lines.append(
                f"{name[:-1]} stripe energy down {statistics.median(gains):.1f} dB (median over "
                f"{len(gains)} file(s); range {min(gains):.1f} to {max(gains):.1f} dB)"
            )
    measured = [r for r in records if r.get("status") == "done" and r.get("report")]
    for step in steps():
        if step.scope == "frame":
            lines += step.summary(measured)
    moved = _finite([r.get("lowpass_change_mm") for r in reps])
    if moved:
        lines.append(f"low-pass depth moved at most {max(moved):.2f} mm RMS (the scene itself)")
    if changed == 0:
        lines.append(
            "nothing was changed: the outputs hold the input depth"
            + ("" if found else " (no stripe found)")
        )
    return lines
