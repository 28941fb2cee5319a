"""The scene format: the ground truth of one scene as a versioned ``.npz``.

Contract (``format_version`` 1; docs/io.md), arrays in the file:

* ``depth``: float32 (H, W), metres;
* ``reflectance``: float32 (H, W), near-infrared reflectance in (0, 1];
* ``mask`` (optional): bool (H, W), True where the scene is known; where it is False the depth and
  reflectance are not used (they may hold NaN);
* ``content`` = ``"tof_fpn_torch.scene"``, ``format_version`` (int), ``meta`` (a JSON object, may
  be empty).

Wherever the mask is True (everywhere without a mask) depth is finite and > 0 and reflectance
finite in (0, 1], as :class:`tof_fpn_torch.sim.Scene` requires. In memory a :class:`SceneData`
holds (1, 1, H, W) tensors, so ``Scene(s.depth, s.reflectance)`` builds a simulator scene from a
fully known one; :func:`scene_from_sim` goes the other way (reading the scene by attribute, without
importing :mod:`tof_fpn_torch.sim`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from ..runtime.validity import valid_mask
from ._common import FormatError
from ._container import jsonable, read_container, write_container

__all__ = [
    "SCENE_CONTENT",
    "SCENE_FORMAT_VERSION",
    "SceneData",
    "read_scene",
    "scene_from_sim",
    "write_scene",
]

SCENE_CONTENT = "tof_fpn_torch.scene"
SCENE_FORMAT_VERSION: int = 1


def _map(x, name: str, floating: bool = True) -> torch.Tensor:
    """(H, W) or (1, 1, H, W) tensor / array -> a (1, 1, H, W) CPU tensor (float32 or bool)."""
    if isinstance(x, np.ndarray):
        x = torch.from_numpy(x)
    if not isinstance(x, torch.Tensor):
        raise ValueError(f"{name} must be a torch.Tensor or numpy.ndarray, got {type(x).__name__}")
    if floating and not x.is_floating_point():
        raise ValueError(f"{name} must be floating point, got dtype {x.dtype}")
    if not floating and x.dtype != torch.bool:
        raise ValueError(f"{name} must be a bool map (True = known), got dtype {x.dtype}")
    if x.dim() == 2:
        x = x[None, None]
    if x.dim() != 4 or x.shape[:2] != (1, 1) or 0 in x.shape:
        raise ValueError(f"{name} must have shape (H, W) or (1, 1, H, W), got {list(x.shape)}")
    return x.detach().to("cpu", torch.float32 if floating else torch.bool)


@dataclass
class SceneData:
    """Ground truth of one scene.

    Args:
        depth: (H, W) or (1, 1, H, W) floating, metres.
        reflectance: same shape, near-infrared reflectance in (0, 1].
        mask: optional bool map of the same shape, True where the scene is known.
        meta: JSON data describing the scene (source, materials, ...).

    Wherever ``mask`` is True (everywhere without one) depth must be finite and > 0 and
    reflectance finite in (0, 1]; ``ValueError`` says how many pixels break that.
    """

    depth: torch.Tensor
    reflectance: torch.Tensor
    mask: torch.Tensor | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.depth = _map(self.depth, "depth")
        self.reflectance = _map(self.reflectance, "reflectance")
        if self.reflectance.shape != self.depth.shape:
            raise ValueError(
                f"reflectance must have the shape of depth {list(self.depth.shape)}, got "
                f"{list(self.reflectance.shape)}"
            )
        known = torch.ones_like(self.depth, dtype=torch.bool)
        if self.mask is not None:
            self.mask = _map(self.mask, "mask", floating=False)
            if self.mask.shape != self.depth.shape:
                raise ValueError(
                    f"mask must have the shape of depth {list(self.depth.shape)}, got "
                    f"{list(self.mask.shape)}"
                )
            known = self.mask
        bad = int((known & ~valid_mask(self.depth)).sum())
        if bad:
            raise ValueError(f"depth must be finite and > 0 m where known, got {bad} pixel(s)")
        r = self.reflectance
        bad = int((known & ~(torch.isfinite(r) & (r > 0) & (r <= 1))).sum())
        if bad:
            raise ValueError(
                f"reflectance must be finite in (0, 1] where known, got {bad} pixel(s) outside"
            )
        if not isinstance(self.meta, dict):
            raise ValueError(f"meta must be a dict, got {type(self.meta).__name__}")
        self.meta = jsonable(self.meta)


def write_scene(path, scene: SceneData, *, compress: bool = False) -> Path:
    """Write a :class:`SceneData` as a version-1 scene ``.npz`` (deterministic bytes)."""
    if not isinstance(scene, SceneData):
        raise ValueError(f"scene must be a SceneData, got {type(scene).__name__}")
    arrays = {"depth": scene.depth[0, 0].numpy(), "reflectance": scene.reflectance[0, 0].numpy()}
    if scene.mask is not None:
        arrays["mask"] = scene.mask[0, 0].numpy()
    return write_container(path, SCENE_CONTENT, SCENE_FORMAT_VERSION, scene.meta, arrays, compress)


def read_scene(path) -> SceneData:
    """Read a scene ``.npz`` and check it against the contract (``FormatError`` if not).

    Returns:
        :class:`SceneData` with (1, 1, H, W) depth (metres, float32), reflectance (float32) and
        mask (bool) or None.
    """
    arrays, meta = read_container(
        path, SCENE_CONTENT, SCENE_FORMAT_VERSION, ("depth", "reflectance"), ("mask",)
    )
    want = {"depth": np.float32, "reflectance": np.float32, "mask": np.bool_}
    for key, arr in arrays.items():
        if arr.dtype != want[key] or arr.ndim != 2:
            raise FormatError(
                f"{path}: {key!r} must be {np.dtype(want[key])} (H, W), got {arr.dtype} {arr.shape}"
            )
    try:
        return SceneData(arrays["depth"], arrays["reflectance"], mask=arrays.get("mask"), meta=meta)
    except ValueError as exc:
        raise FormatError(f"{path}: not a valid scene: {exc}") from exc


def scene_from_sim(scene, index: int = 0, *, meta: dict | None = None) -> SceneData:
    """The ``index``-th scene of a :class:`tof_fpn_torch.sim.Scene` batch as :class:`SceneData`.

    ``scene``: anything with ``depth`` and ``reflectance`` of shape (B, 1, H, W) (metres and
    (0, 1]); its optional reference amplitude is not part of the scene format."""
    for attr in ("depth", "reflectance"):
        if not isinstance(getattr(scene, attr, None), torch.Tensor):
            raise ValueError(
                f"scene must be a simulator Scene with a .{attr} tensor, got {scene!r}"
            )
    b = scene.depth.shape[0] if scene.depth.dim() == 4 else 0
    if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < b:
        raise ValueError(f"index must be an int in [0, {b}) (the scene batch), got {index!r}")
    info = {"source": "tof_fpn_torch.sim", **(meta or {})}
    sl = slice(index, index + 1)
    return SceneData(scene.depth[sl], scene.reflectance[sl], meta=info)
