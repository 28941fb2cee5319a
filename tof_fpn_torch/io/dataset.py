"""A :class:`torch.utils.data.Dataset` over a folder of depth / amplitude frames.

Naming rule (one frame per item; suffixes of :mod:`.pairs`):

* ``<name>.npz`` / ``<name>.h5`` / ``<name>.hdf5``: one file holding the frame's depth and
  amplitude (``depth`` and ``amplitude`` arrays / datasets);
* ``<name>_depth.<ext>`` + ``<name>_amplitude.<ext>`` with ``<ext>`` one of ``.npy``, ``.png``,
  ``.tif``, ``.tiff``, ``.bin``, ``.raw`` (the same for both; raw files need ``height`` and
  ``width``).

Files with other suffixes are ignored. A ``_depth`` file without its ``_amplitude`` (or the
reverse), a pair with two suffixes, a single-array file without either ending and a name used
twice raise ``ValueError`` when the dataset is built; depth and amplitude of different shapes, a
file holding several frames or a frame with no valid pixel raise when the item is read.

Items are ``(depth, amplitude, info)``: float32 (1, H, W) depth in metres with NaN for invalid,
float32 (1, H, W) amplitude in camera units, and ``info = {"name", "index", "depth_path",
"amplitude_path"}`` (str / int, so the default collate makes lists). The dataset holds only paths
and numbers, so it pickles to ``DataLoader`` workers (``num_workers > 0``).
"""

from __future__ import annotations

import os
from pathlib import Path

import torch
from torch.utils.data import Dataset

from .formats import FRAME_SET, PAIR_MEMBER, format_of_name
from .pairs import SUFFIXES, read_pair
from .raw import frame_size

__all__ = ["FrameDataset", "find_frames"]

_ENDINGS = {"_depth": "depth", "_amplitude": "amplitude"}


def find_frames(root, recursive: bool = False) -> list[tuple[str, str, str | None]]:
    """``(name, depth_path, amplitude_path)`` of every frame under ``root`` by the naming rule
    (sorted by name; ``amplitude_path`` None for ``.npz`` / ``.h5``); ``ValueError`` for
    unmatched or ambiguous files."""
    if not isinstance(root, (str, os.PathLike)) or not Path(root).is_dir():
        raise ValueError(f"root must be an existing folder, got {root!r}")
    root = Path(root)
    files = sorted(p for p in (root.rglob("*") if recursive else root.iterdir()) if p.is_file())
    frames: dict[str, tuple[str, str, str | None]] = {}
    singles: dict[str, dict[str, Path]] = {}
    stray, twice = [], []
    for p in files:
        fmt = format_of_name(p.name, by_name=False)
        holds = None if fmt is None else fmt.holds
        name = str(p.relative_to(root).with_suffix("").as_posix())
        if holds == FRAME_SET:
            if name in frames:
                twice.append(name)
            frames[name] = (name, str(p), None)
        elif holds == PAIR_MEMBER:
            ending = next((e for e in _ENDINGS if name.endswith(e)), None)
            if ending is None:
                stray.append(p.name)
                continue
            stem = name[: -len(ending)]
            kind = _ENDINGS[ending]
            if kind in singles.setdefault(stem, {}):
                twice.append(f"{stem} ({kind})")
            singles[stem][kind] = p
    unmatched = []
    for stem, pair in singles.items():
        if set(pair) != {"depth", "amplitude"}:
            unmatched += [str(q.relative_to(root)) for q in pair.values()]
        elif pair["depth"].suffix.lower() != pair["amplitude"].suffix.lower():
            unmatched.append(f"{pair['depth'].name} / {pair['amplitude'].name} (two suffixes)")
        elif stem in frames:
            twice.append(stem)
        else:
            frames[stem] = (stem, str(pair["depth"]), str(pair["amplitude"]))
    problems = []
    if unmatched:
        problems.append(f"unmatched depth / amplitude files {unmatched}")
    if stray:
        problems.append(f"files named neither <name>_depth nor <name>_amplitude {stray}")
    if twice:
        problems.append(f"names given twice {sorted(set(twice))}")
    if problems:
        raise ValueError(
            f"{root}: " + "; ".join(problems) + ". Rule: <name>.npz / <name>.h5 holding both, or "
            "<name>_depth.<ext> + <name>_amplitude.<ext> with one <ext>"
        )
    if not frames:
        raise ValueError(f"{root}: no frames found (suffixes {list(SUFFIXES)})")
    return [frames[k] for k in sorted(frames)]


class FrameDataset(Dataset):
    """Depth / amplitude frames of a folder, one per item (naming rule: module docstring).

    Args:
        root: the folder.
        height, width: frame size of raw ``.bin`` / ``.raw`` files, pixels.
        depth_scale: metres per stored depth unit (default 1 mm for integer files, 1 m for
            floating ones, the HDF5 ``scale_m`` attribute).
        allow_empty: yield frames with no valid pixel instead of raising.
        recursive: also look in sub-folders (names are then relative paths).

    Items: ``(depth (1, H, W) metres NaN-invalid, amplitude (1, H, W) camera units, info)``.
    """

    def __init__(
        self,
        root,
        *,
        height: int | None = None,
        width: int | None = None,
        depth_scale: float | None = None,
        allow_empty: bool = False,
        recursive: bool = False,
    ) -> None:
        self.frames = find_frames(root, recursive)
        raw = [d for _, d, _ in self.frames if format_of_name(d, by_name=False).needs_size]
        if raw and (height is None or width is None):
            raise ValueError(f"raw files {raw[:3]} need height and width (pixels)")
        if height is not None or width is not None:
            frame_size(height, width)
        self.height, self.width = height, width
        self.depth_scale = depth_scale
        self.allow_empty = allow_empty

    def __len__(self) -> int:
        return len(self.frames)

    def __getitem__(self, index: int) -> tuple[torch.Tensor, torch.Tensor, dict]:
        if not -len(self) <= index < len(self):
            raise IndexError(f"index {index} out of range for {len(self)} frames")
        index = int(index) % len(self)
        name, depth_path, amplitude_path = self.frames[index]
        depth, amplitude = read_pair(
            depth_path,
            amplitude_path,
            height=self.height,
            width=self.width,
            depth_scale=self.depth_scale,
            allow_empty=self.allow_empty,
        )
        if depth.shape[0] != 1:
            raise ValueError(
                f"{depth_path} holds {depth.shape[0]} frames; the dataset yields one frame per "
                "file (read several with read_pair / read_recording)"
            )
        info = {
            "name": name,
            "index": index,
            "depth_path": depth_path,
            "amplitude_path": amplitude_path or depth_path,
        }
        return depth[0], amplitude[0], info
