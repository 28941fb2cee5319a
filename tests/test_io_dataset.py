"""``FrameDataset``: a folder of frames in any supported format, the naming rule, DataLoader
workers, and clear errors for folders that break the rule."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from tof_fpn_torch import io as tio
from tof_fpn_torch.io import FrameDataset

H, W = 6, 9


def _frame(seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """A (1, 1, H, W) depth in whole mm (metres, NaN holes) and amplitude in whole counts."""
    rng = np.random.default_rng(seed)
    mm = rng.integers(0, 9000, (1, 1, H, W)).astype(np.float64)
    depth = torch.from_numpy((mm / 1000).astype(np.float32))
    depth[mm == 0] = math.nan
    depth[0, 0, 0, 0] = 1.0  # at least one valid pixel
    amp = torch.from_numpy(rng.integers(0, 4096, (1, 1, H, W)).astype(np.float32))
    return depth, amp


@pytest.fixture()
def folder(tmp_path):
    """One frame in each format family (and a file the rule ignores)."""
    layout = {
        "a": ("a.npz", None),
        "b": ("b.h5", None),
        "c": ("c_depth.png", "c_amplitude.png"),
        "d": ("d_depth.npy", "d_amplitude.npy"),
        "e": ("e_depth.tiff", "e_amplitude.tiff"),
        "f": ("f_depth.bin", "f_amplitude.bin"),
    }
    frames = {}
    for i, (name, (dp, ap)) in enumerate(layout.items()):
        frames[name] = _frame(i)
        tio.write_pair(tmp_path / dp, *frames[name], None if ap is None else tmp_path / ap)
    (tmp_path / "README.txt").write_text("not a frame")
    return tmp_path, frames


def test_dataset_reads_every_format_by_the_naming_rule(folder):
    root, frames = folder
    ds = FrameDataset(root, height=H, width=W)
    assert len(ds) == 6
    assert [n for n, *_ in ds.frames] == ["a", "b", "c", "d", "e", "f"]
    for i, name in enumerate("abcdef"):
        depth, amp, info = ds[i]
        assert depth.shape == amp.shape == (1, H, W) and depth.dtype == torch.float32
        torch.testing.assert_close(depth, frames[name][0][0], rtol=0, atol=0, equal_nan=True)
        assert torch.equal(amp, frames[name][1][0])
        assert info["name"] == name and info["index"] == i
    assert ds[-1][2]["name"] == "f"
    with pytest.raises(IndexError):
        ds[6]


def test_dataset_with_dataloader_workers(folder):
    root, frames = folder
    ds = FrameDataset(root, height=H, width=W)
    loader = DataLoader(ds, batch_size=4, num_workers=2, shuffle=False)
    names, depths = [], []
    for depth, amp, info in loader:
        assert depth.shape[1:] == amp.shape[1:] == (1, H, W)
        names += info["name"]
        depths.append(depth)
    assert names == list("abcdef")
    want = torch.cat([frames[n][0] for n in names])
    torch.testing.assert_close(torch.cat(depths), want, rtol=0, atol=0, equal_nan=True)


def test_dataset_recursive_names_are_relative_paths(tmp_path):
    (tmp_path / "day1").mkdir()
    tio.write_pair(tmp_path / "day1" / "x.npz", *_frame(0))
    tio.write_pair(tmp_path / "y.npz", *_frame(1))
    assert len(FrameDataset(tmp_path)) == 1
    assert [n for n, *_ in FrameDataset(tmp_path, recursive=True).frames] == ["day1/x", "y"]


@pytest.mark.parametrize(
    ("files", "match"),
    [
        (["x_depth.png"], r"unmatched depth / amplitude files \['x_depth.png'\]"),
        (["x_amplitude.npy"], r"unmatched .*\['x_amplitude.npy'\]"),
        (["x_depth.png", "x_amplitude.tif"], r"x_depth.png / x_amplitude.tif \(two suffixes\)"),
        (["x.png"], r"named neither <name>_depth nor <name>_amplitude \['x.png'\]"),
        (["x.npz", "x_depth.npy", "x_amplitude.npy"], r"names given twice \['x'\]"),
        (["x.npz", "x.h5"], r"names given twice \['x'\]"),
        (["x_depth.png", "x_depth.tif", "x_amplitude.png"], r"names given twice \['x \(depth\)'\]"),
    ],
)
def test_dataset_mismatched_pairs_raise(tmp_path, files, match):
    for name in files:  # the rule is checked before any file is read: empty files will do
        (tmp_path / name).write_bytes(b"")
    with pytest.raises(ValueError, match=match):
        FrameDataset(tmp_path)


def test_dataset_errors_when_reading(tmp_path):
    d, a = _frame(0)
    tio.write_pair(tmp_path / "s_depth.npy", d, a, tmp_path / "s_amplitude.npy")
    tio.write_npy(tmp_path / "s_amplitude.npy", torch.ones(1, 1, H, W + 1), "amplitude")
    with pytest.raises(ValueError, match=r"same shape, got \[1, 1, 6, 9\] and \[1, 1, 6, 10\]"):
        FrameDataset(tmp_path)[0]
    (tmp_path / "s_depth.npy").unlink()
    (tmp_path / "s_amplitude.npy").unlink()
    tio.write_pair(tmp_path / "m.npz", torch.cat([d, d]), torch.cat([a, a]))
    with pytest.raises(ValueError, match="holds 2 frames; the dataset yields one frame per file"):
        FrameDataset(tmp_path)[0]
    tio.write_pair(tmp_path / "m.npz", torch.full_like(d, math.nan), a)
    with pytest.raises(ValueError, match="no valid pixel"):
        FrameDataset(tmp_path)[0]
    assert bool(FrameDataset(tmp_path, allow_empty=True)[0][0].isnan().all())


def test_dataset_argument_errors(tmp_path):
    with pytest.raises(ValueError, match="root must be an existing folder"):
        FrameDataset(tmp_path / "missing")
    with pytest.raises(ValueError, match="no frames found"):
        FrameDataset(tmp_path)
    d, a = _frame(0)
    tio.write_pair(tmp_path / "r_depth.raw", d, a, tmp_path / "r_amplitude.raw")
    with pytest.raises(ValueError, match="need height and width"):
        FrameDataset(tmp_path)
    with pytest.raises(ValueError, match="width must be an int >= 1"):
        FrameDataset(tmp_path, height=H, width=0)
    with pytest.raises(tio.FormatError, match="not a whole number of 7 x 9"):
        FrameDataset(tmp_path, height=7, width=W)[0]
