"""``tof-fpn clean --temporal``: the temporal filter over the frames of each multi-frame file.

The stage (:class:`~tof_fpn_torch.runtime.TemporalSequence`) runs after the FPN stage and the
denoiser, frame after frame in file order, its state carried from frame to frame within one frame
set (a recording ``.h5`` / ``.mkv`` / bag, an HDF5 group, a multi-frame TIFF or ``.npy``) and
started afresh for the next. A frame set of one frame has no time order to filter over: nothing
is done to it, and the file's record says so (a folder of single-frame files is not a recording:
frames of different files are never filtered together). Nor is a set whose timestamps do not
increase.

The guard's noise: ``k`` of the noise law ``k / A``
(:func:`~tof_fpn_torch.runtime.noise.estimate_noise_k`) measured on the set's first frame (causal:
the filter then runs live), else, where that finds nothing, the frame's wavelet noise level as a
constant, else :data:`~tof_fpn_torch.constants.TEMPORAL_SIGMA`.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from .. import constants as K
from ..runtime import TemporalSequence, valid_mask
from ..runtime.noise import estimate_noise_k, estimate_sigma

__all__ = ["apply_temporal", "temporal_lines", "temporal_module"]


def temporal_module(alpha: float, guard: float, persistence: int) -> TemporalSequence:
    """The stage's settings as a module (checked; ``sigma`` and ``noise_k`` are set per set)."""
    return TemporalSequence(alpha=alpha, guard=guard, persistence=persistence)


def _noise(depth: torch.Tensor, amplitude: torch.Tensor) -> tuple[float, float, str]:
    """``(sigma, noise_k, how)`` for the guard from one (1, 1, H, W) frame."""
    valid = valid_mask(depth, amplitude)
    work = torch.where(valid, depth, torch.zeros_like(depth))
    k = float(estimate_noise_k(work, amplitude, valid))
    if math.isfinite(k) and k > 0:
        return 0.0, k, "noise law k / A from the first frame"
    s = float(estimate_sigma(work, valid))
    if math.isfinite(s) and s > 0:
        return s, 0.0, "constant noise level of the first frame"
    return K.TEMPORAL_SIGMA, 0.0, "default noise level"


def apply_temporal(
    settings: TemporalSequence,
    depth: torch.Tensor,
    amplitude: torch.Tensor,
    timestamps_s: np.ndarray | None = None,
) -> tuple[torch.Tensor, dict]:
    """The filter over the (T, 1, H, W) frames of one set in order: ``(out, record)``; the record
    says whether it was applied and why not, and the noise the guard used."""
    t = int(depth.shape[0])
    if t < 2:
        return depth, {"applied": False, "frames": t, "reason": "one frame: no time order"}
    if timestamps_s is not None and not bool(np.all(np.diff(timestamps_s) > 0)):
        return depth, {"applied": False, "frames": t, "reason": "timestamps do not increase"}
    sigma, k, how = _noise(depth[:1], amplitude[:1])
    module = TemporalSequence(settings.alpha, settings.guard, sigma, k, settings.persistence)
    with torch.no_grad():
        out, rec = module.run(depth, amplitude)
    restarts = int(rec["restarted"].sum())
    record = {
        "applied": True,
        "frames": t,
        "noise": how,
        "sigma_m": sigma,
        "noise_k": k,
        "restarts": restarts,  # guard restarts after the first frame (motion and false alarms)
    }
    return out, record


def temporal_lines(records: list[dict]) -> list[str]:
    """What the command prints about the stage, from the ``done`` records (their ``temporal``)."""
    sets = [s for r in records for s in (r.get("temporal") or [])]
    if not sets:
        return []
    applied = [s for s in sets if s["applied"]]
    skipped = [s for s in sets if not s["applied"]]
    lines = [
        f"temporal: applied to {len(applied)} frame set(s) "
        f"({sum(s['frames'] for s in applied)} frames)"
    ]
    if skipped:
        why = sorted({s["reason"] for s in skipped})
        lines.append(
            f"temporal: NOT applied to {len(skipped)} frame set(s) ({'; '.join(why)}): it "
            "filters the frames of one multi-frame file in time order, never frames of "
            "different files"
        )
    return lines
