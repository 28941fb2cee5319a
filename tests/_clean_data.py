"""Small synthetic frame folders for the ``tof-fpn clean`` tests (seeded, written with the file
layer's own writers, so the files are what the package reads)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from tof_fpn_torch import io as tio


def frame(rng: np.random.Generator, h: int = 32, w: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """Depth (metres, a few invalid pixels, stripes at pi and 2 pi / 3) and amplitude (counts)."""
    x = np.arange(w)
    stripes = 0.01 * np.cos(np.pi * x) + 0.006 * np.cos(2 * np.pi / 3 * x)
    depth = (
        1.5
        + 0.3 * np.linspace(0, 1, h)[:, None]
        + stripes[None]
        + 0.002 * rng.standard_normal((h, w))
    )
    depth[rng.random((h, w)) < 0.02] = np.nan
    amplitude = np.rint(rng.uniform(20, 120, (h, w)))  # low sensing (A < 300)
    return depth.astype(np.float32), amplitude.astype(np.float32)


def png_folder(
    root: Path, n: int, seed: int = 0, h: int = 32, w: int = 40, sub_every: int = 3
) -> Path:
    """``n`` PNG pairs ``fNNN_depth.png`` / ``fNNN_amplitude.png``, every ``sub_every``-th in a
    sub-folder ``sub/``."""
    rng = np.random.default_rng(seed)
    for i in range(n):
        folder = root / "sub" if sub_every and i % sub_every == 1 else root
        os.makedirs(folder, exist_ok=True)
        d, a = frame(rng, h, w)
        tio.write_png(folder / f"f{i:03d}_depth.png", d, "depth")
        tio.write_png(folder / f"f{i:03d}_amplitude.png", a, "amplitude")
    return root


def tree(root: Path, skip: tuple[str, ...] = ("manifest.jsonl",)) -> dict[str, bytes]:
    """Every file under ``root`` (relative path -> bytes), except the names in ``skip``."""
    out = {}
    for p in sorted(root.rglob("*")):
        if p.is_file() and p.name not in skip:
            out[p.relative_to(root).as_posix()] = p.read_bytes()
    return out
