"""Recordings whose camera or scene moved: the diagnosis keeps the frames of the largest pose
(``tof_fpn_torch.diagnosis.poses``), on synthetic frames and on the real ESPROS TOFcam635 point
cloud as the epc-tofcam-toolkit wrote it (``tests/data/real``; missing: the test fails)."""

from __future__ import annotations

import math

import pytest
import torch
from conftest import real_capture

from tof_fpn_torch import io as tio
from tof_fpn_torch.diagnosis import diagnose
from tof_fpn_torch.diagnosis.poses import one_pose, pose_groups

ESPROS_CLOUD = "espros_tofcam635/point_cloud_w544c005_250527_134722.h5"
META = {"modulation_frequency_hz": None, "integration_time_us": None, "n_phases": None}


def _frames(offsets_mm, noise_mm=2.0, seed=0):
    """Frames (T, 1, 40, 50) of a slanted textured surface moved along the axis by
    ``offsets_mm``, with white noise."""
    g = torch.Generator().manual_seed(seed)
    y, x = torch.meshgrid(torch.arange(40.0), torch.arange(50.0), indexing="ij")
    surface = 1.5 + 0.004 * x + 0.002 * y + 0.003 * torch.sin(x / 3)
    out = [
        surface + o * 1e-3 + noise_mm * 1e-3 * torch.randn(40, 50, generator=g, dtype=torch.float32)
        for o in offsets_mm
    ]
    return torch.stack(out)[:, None]


def test_frames_of_one_pose_are_grouped_and_a_moved_pose_is_not():
    # 10 mm is 5 noise sd: another pose; two copies of a frame join their original
    depth = _frames([0, 0, 0, 10, 10, 30, 0])
    depth[2] = depth[1]
    assert pose_groups(depth[:, 0]) == [[0, 1, 2, 6], [3, 4], [5]]
    still = _frames([0, 0, 0, 0], seed=1)
    assert pose_groups(still[:, 0]) == [[0, 1, 2, 3]]
    assert pose_groups(still[:1, 0]) == [[0]]


def test_one_pose_keeps_the_largest_group_with_its_timestamps_and_says_so():
    depth = _frames([0, 12, 0, 12, 0])
    rec = tio.Recording(depth, torch.full_like(depth, 100.0), META, timestamps_s=torch.arange(5.0))
    kept, note = one_pose(rec)
    assert kept.depth.shape[0] == 3
    assert torch.equal(kept.depth, depth[[0, 2, 4]])
    assert kept.timestamps_s.tolist() == [0.0, 2.0, 4.0]
    assert "2 poses" in note and "frames 0, 2, 4" in note and "the 3 frames" in note
    same, none = one_pose(tio.Recording(depth[[0, 2]], torch.ones_like(depth[[0, 2]]), META))
    assert none is None and same.depth.shape[0] == 2


@pytest.mark.slow
def test_the_espros_point_cloud_is_diagnosed_from_the_file_as_the_toolkit_wrote_it():
    """All 14 frames of the file (6 poses; the scene estimated from the frames): once refused
    (no pixel with a clear signal); the 8 frames of the main pose are diagnosed, a note says so,
    and the held-out fit is finite and improves."""
    path = real_capture(ESPROS_CLOUD)
    assert tio.read_espros_hdf5(path).depth.shape[0] == 14
    diag = diagnose(str(path), None, replicates=0)
    assert diag.obs.frames == 8 and diag.obs.scene_estimated
    notes = diag.report["recording"]["notes"]
    assert any("6 poses" in n and "frames 0-3, 10-13" in n for n in notes), notes
    before, after = diag.report["fit"]["before"], diag.report["fit"]["after"]
    assert math.isfinite(before["heldout_nll"]) and math.isfinite(after["heldout_nll"])
    assert diag.effects, diag.report["verdict"]
    assert after["heldout_nll"] < before["heldout_nll"] - 1000
