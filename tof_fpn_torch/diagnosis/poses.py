"""The frames of one pose of a recording whose camera or scene moved.

Without a scene the diagnosis estimates it from the recording (its temporal median, smoothed),
which is only the scene when every frame shows the same one: frames of other poses make every
pixel's temporal spread a mixture of distances, and the depth likelihood has no pixel left.
:func:`one_pose` groups the frames by pose and keeps the largest group.

Two frames show one pose when the median absolute difference of their depths is below
:data:`SAME_POSE_Z` times the noise of a frame difference. That noise is taken from the pair of
consecutive frames whose difference is quietest: the median absolute second difference along
the rows of a difference image, over ``sqrt(6)`` (white noise's share; a surface that moved adds
curvature and raises it). Each frame joins the first group whose first frame shows its pose;
frames that are exact copies (some recorders repeat a frame) join their original.
"""

from __future__ import annotations

import math

import torch

__all__ = ["SAME_POSE_Z", "one_pose", "pose_groups"]

#: Two frames show one pose when the median absolute difference of their depths is below this
#: many times the noise of a frame difference (the quietest pair's). On the ESPROS TOFcam635
#: point cloud of the test data the frames of its main pose differ by 0.6-0.85 of that noise,
#: the nearest other pose by 5.7 of it.
SAME_POSE_Z: float = 3.0


def _second_difference_noise(diff: torch.Tensor) -> float:
    c = diff[:, 2:] - 2 * diff[:, 1:-1] + diff[:, :-2]
    c = c[torch.isfinite(c)]
    if c.numel() < 16:
        return math.nan
    return float(c.abs().median()) / math.sqrt(6.0)


def _median_abs(diff: torch.Tensor) -> float:
    ok = torch.isfinite(diff)
    return float(diff[ok].abs().median()) if int(ok.sum()) >= 16 else math.nan


def pose_groups(depth: torch.Tensor) -> list[list[int]]:
    """Frames of ``depth`` (T, H, W; NaN invalid) grouped by pose (module docstring), in order
    of their first frame. One group when fewer than two frames or no pair can be compared. Each
    frame is compared with the first frame of every group so far (and the noise taken from the
    pairs of consecutive frames), on at most 64 of the rows."""
    t = depth.shape[0]
    if t < 2:
        return [list(range(t))]
    d = depth[:, :: max(1, depth.shape[1] // 64)].to(torch.float64)
    noise = [_second_difference_noise(d[i + 1] - d[i]) for i in range(t - 1)]
    noise = [n for n in noise if math.isfinite(n) and n > 0]
    if not noise:
        return [list(range(t))]
    limit = SAME_POSE_Z * min(noise)
    groups: list[list[int]] = []
    for i in range(t):
        for g in groups:
            if _median_abs(d[i] - d[g[0]]) < limit:
                g.append(i)
                break
        else:
            groups.append([i])
    return groups


def one_pose(recording):
    """``(recording, note)``: the frames of the largest pose group of ``recording`` (the first
    such group on a tie) and a note saying which were kept; ``note`` None when every frame shows
    one pose (the recording is returned as it is)."""
    groups = pose_groups(recording.depth[:, 0])
    if len(groups) < 2:
        return recording, None
    keep = max(groups, key=len)
    idx = torch.tensor(keep)
    ts = recording.timestamps_s
    rec = type(recording)(
        recording.depth[idx],
        recording.amplitude[idx],
        dict(recording.meta),
        timestamps_s=None if ts is None else ts[idx],
        raw=None if recording.raw is None else recording.raw[idx],
    )
    t = recording.depth.shape[0]
    note = (
        f"the camera or the scene moved: the {t} frames show {len(groups)} poses (frames "
        f"{_ranges(keep)} one of them); the scene is estimated from the frames of one pose, so "
        f"the {len(keep)} frames of the largest group are diagnosed and the other "
        f"{t - len(keep)} left out"
    )
    return rec, note


def _ranges(idx: list[int]) -> str:
    out, start = [], idx[0]
    for a, b in zip(idx, idx[1:] + [None], strict=True):
        if b is None or b != a + 1:
            out.append(f"{start}" if start == a else f"{start}-{a}")
            start = b
    return ", ".join(out)
