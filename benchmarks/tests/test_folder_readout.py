"""The folder-learned read-out offset on a camera folder of the generator (slow: one folder of six
171 x 229 frames is learned)."""

from __future__ import annotations

import camera_folders as cf
import imageio.v3 as iio
import numpy as np
import pytest
import torch

from tof_fpn_torch.analysis import learn_folder_pattern


@pytest.mark.slow
def test_a_read_out_that_predicts_held_out_scenes_a_fifth_better_is_learned(tmp_path):
    """Boxes with a complex read-out offset (dev seed 5): the read-out model predicts the held-out
    half of the scenes about a fifth better than plain offsets. It is chosen and every frame gains
    (with a 25 % margin it was left to plain offsets, and the frames gained 0.3 dB)."""
    t = cf.make_folder(tmp_path, "boxes", "complex_offset", 5, n_frames=6, height=171, width=229)
    frames = tmp_path / "frames"
    depth = np.stack([iio.imread(frames / f"{s}_depth.png") for s in t["stems"]]) / 1000.0
    amp = np.stack([iio.imread(frames / f"{s}_amplitude.png") for s in t["stems"]]).astype(float)
    d, a = torch.from_numpy(depth)[:, None], torch.from_numpy(amp)[:, None]
    learned = learn_folder_pattern(d, a)
    assert learned.readout is not None, learned.summary()
    held = learned.evidence["held_out_loss"]
    assert 0.75 < held["readout"] / held["offset"] < 0.9  # the case this test is about
    y = learned.readout.module()(learned.pattern.module()(d, a), a)[:, 0].numpy()
    ok = (depth > 0) & np.isfinite(t["depth"]) & ~t["flying"]
    for i in range(depth.shape[0]):
        m = ok[i]
        e_in = np.sqrt(np.mean((depth[i] - t["depth"][i])[m] ** 2))
        e_out = np.sqrt(np.mean((y[i] - t["depth"][i])[m] ** 2))
        assert 20 * np.log10(e_in / e_out) > 0.5, (i, e_in, e_out)
