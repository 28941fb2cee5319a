"""Scenes for the simulator: a validated container and two deterministic generators.

* :func:`synthetic_scene` -- like Fig. 7 of Georgiev et al. (SAS 2015): fine details, edges and
  contours, depth in ``[0, 7.5]`` m, amplitude in ``[0, 300]`` (the low-sensing range).
* :func:`planar_scene` -- the real-case layout of Sec. IV-A: planar objects facing the camera at
  several depths, made of materials of different reflectance (plain and textured).

Both are deterministic functions of ``seed`` (a CPU ``torch.Generator``), independent of device.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from .. import constants as K
from ._synthetic import _one_synthetic, _u

__all__ = ["Scene", "planar_scene", "synthetic_scene"]


def _check_map(x, name: str) -> None:
    if not isinstance(x, torch.Tensor):
        raise ValueError(f"{name} must be a torch.Tensor of shape (B, 1, H, W), got {type(x)}")
    if x.dim() != 4 or x.shape[1] != 1:
        raise ValueError(f"{name} must have shape (B, 1, H, W), got {list(x.shape)}")
    if not x.is_floating_point():
        raise ValueError(f"{name} must be floating point, got dtype {x.dtype}")


def _count(mask: torch.Tensor) -> int:
    return int(mask.sum())


@dataclass
class Scene:
    """Ground truth of a scene: depth and reflectance, optionally a reference amplitude.

    Args:
        depth: (B, 1, H, W) float, metres, finite and > 0 everywhere (a ground truth has no
            invalid pixels; mask them out of metrics instead).
        reflectance: (B, 1, H, W) float, near-infrared reflectance in ``(0, 1]`` (zero
            reflectance returns no light and is rejected).
        amplitude: optional (B, 1, H, W) float >= 0, the ground-truth amplitude map used by the
            depth-domain model (:mod:`tof_fpn_torch.sim.depth_model`); the raw simulator derives
            amplitudes itself and ignores it.

    Raises:
        ValueError: for wrong shapes, NaN/inf or non-positive depth, reflectance outside
            ``(0, 1]``, negative or non-finite amplitude.
    """

    depth: torch.Tensor
    reflectance: torch.Tensor
    amplitude: torch.Tensor | None = None

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> Scene:
        _check_map(self.depth, "depth")
        _check_map(self.reflectance, "reflectance")
        if self.reflectance.shape != self.depth.shape:
            raise ValueError(
                f"reflectance must have the shape of depth {list(self.depth.shape)}, "
                f"got {list(self.reflectance.shape)}"
            )
        bad = _count(~torch.isfinite(self.depth))
        if bad:
            raise ValueError(f"depth must be finite, got {bad} NaN/inf pixel(s)")
        bad = _count(self.depth <= 0)
        if bad:
            raise ValueError(
                f"depth must be > 0 m, got {bad} pixel(s) <= 0 (min {float(self.depth.min()):g})"
            )
        r = self.reflectance
        bad = _count(~torch.isfinite(r))
        if bad:
            raise ValueError(f"reflectance must be finite, got {bad} NaN/inf pixel(s)")
        bad = _count((r <= 0) | (r > 1))
        if bad:
            raise ValueError(
                f"reflectance must lie in (0, 1] (zero reflectance returns no signal), got {bad} "
                f"pixel(s) outside, range [{float(r.min()):g}, {float(r.max()):g}]"
            )
        if self.amplitude is not None:
            _check_map(self.amplitude, "amplitude")
            if self.amplitude.shape != self.depth.shape:
                raise ValueError(
                    f"amplitude must have the shape of depth {list(self.depth.shape)}, "
                    f"got {list(self.amplitude.shape)}"
                )
            bad = _count(~torch.isfinite(self.amplitude) | (self.amplitude < 0))
            if bad:
                raise ValueError(f"amplitude must be finite and >= 0, got {bad} bad pixel(s)")
        return self

    @property
    def shape(self) -> torch.Size:
        return self.depth.shape

    def to(self, device=None, dtype=None) -> Scene:
        amp = None if self.amplitude is None else self.amplitude.to(device=device, dtype=dtype)
        return Scene(
            self.depth.to(device=device, dtype=dtype),
            self.reflectance.to(device=device, dtype=dtype),
            amp,
        )


def _check_size(height: int, width: int, minimum: int = 16) -> None:
    for name, v in (("height", height), ("width", width)):
        if isinstance(v, bool) or not isinstance(v, int) or v < minimum:
            raise ValueError(f"{name} must be an int >= {minimum}, got {v!r}")


def _check_seed_batch(seed: int, batch: int) -> None:
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ValueError(f"seed must be an int >= 0, got {seed!r}")
    if isinstance(batch, bool) or not isinstance(batch, int) or batch < 1:
        raise ValueError(f"batch must be an int >= 1, got {batch!r}")


def synthetic_scene(
    height: int = K.CAMCUBE_SIZE,
    width: int = K.CAMCUBE_SIZE,
    *,
    seed: int = 0,
    batch: int = 1,
    depth_range: tuple[float, float] = (0.3, 7.45),
    amplitude_max: float = K.LOW_SENSING_THRESHOLD,
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
) -> Scene:
    """A synthetic scene like the paper's Fig. 7, deterministic from ``seed``.

    Slanted background wall, fronto-parallel boxes (step edges), a wedge, a hemisphere, concentric
    depth rings (contours), a Siemens star (radial detail down to one pixel), 1-3 px bars, a
    sinusoidal depth grating and a near-black object. Amplitudes are per-object "materials" in
    ``[0, amplitude_max]`` with textures, i.e. the low-sensing range ``A < 300`` of Sec. IV-B.

    Args:
        height, width: image size (>= 16), default 204 x 204 (PMD CamCube 2.0).
        seed: int >= 0; the scene depends only on it (not on device or dtype).
        batch: number of scenes; scene ``b`` uses seed ``seed + b``.
        depth_range: ``(min, max)`` depth in metres, ``0 < min < max``. The default max 7.45 m
            stays inside the 20 MHz unambiguous range (7.49 m) so the raw simulator does not wrap.
        amplitude_max: top of the amplitude range (> 0), 300 by default.

    Returns:
        :class:`Scene` with depth, ``amplitude`` in ``[0, amplitude_max]`` and
        ``reflectance = clamp(amplitude / amplitude_max, 0.01, 1)``.
    """
    _check_size(height, width)
    _check_seed_batch(seed, batch)
    dmin, dmax = (float(v) for v in depth_range)
    if not (math.isfinite(dmin) and math.isfinite(dmax) and 0 < dmin < dmax):
        raise ValueError(f"depth_range must be (min, max) with 0 < min < max, got {depth_range!r}")
    amax = float(amplitude_max)
    if not (math.isfinite(amax) and amax > 0):
        raise ValueError(f"amplitude_max must be finite and > 0, got {amplitude_max!r}")
    depths, amps = [], []
    for b in range(batch):
        g = torch.Generator().manual_seed(seed + b)
        d, a = _one_synthetic(height, width, g, dmin, dmax, amax)
        depths.append(d)
        amps.append(a)
    depth = torch.stack(depths)[:, None].to(device=device, dtype=dtype)
    amp = torch.stack(amps)[:, None].to(device=device, dtype=dtype)
    refl = torch.clamp(amp / amax, 0.01, 1.0)
    return Scene(depth=depth, reflectance=refl, amplitude=amp)


#: Near-infrared reflectances of the materials used by :func:`planar_scene`.
MATERIALS: dict[str, float] = {
    "white paper": 0.85,
    "grey card": 0.45,
    "wood": 0.35,
    "black cloth": 0.04,
    "blue paint": 0.25,
}


def planar_scene(
    height: int = K.CAMCUBE_SIZE,
    width: int = K.CAMCUBE_SIZE,
    *,
    seed: int = 0,
    batch: int = 1,
    depths: tuple[float, ...] = (1.2, 1.8, 2.4, 3.0, 3.6),
    wall_depth: float = 4.5,
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
) -> Scene:
    """The real-case layout of Sec. IV-A: fronto-parallel planar boards at several depths.

    A back wall at ``wall_depth`` and one board per entry of ``depths`` (farthest painted first,
    so nearer boards occlude). Board ``k`` gets a material from :data:`MATERIALS` (plain) or a
    texture (checkerboard of white/black, or colour stripes) to model "materials of different
    reflection or painted in different color textures"; sizes shrink with depth (perspective).

    Returns:
        :class:`Scene` with depth, reflectance and a reference ``amplitude`` proxy
        ``300 * reflectance * (1 m / depth)^2`` (the raw simulator computes real amplitudes).
    """
    _check_size(height, width)
    _check_seed_batch(seed, batch)
    ds = [float(d) for d in depths]
    if not ds or any(not (math.isfinite(d) and d > 0) for d in ds):
        raise ValueError(
            f"depths must be a non-empty sequence of finite values > 0, got {depths!r}"
        )
    wd = float(wall_depth)
    if not (math.isfinite(wd) and wd > max(ds)):
        raise ValueError(
            f"wall_depth must be finite and > max(depths) = {max(ds)}, got {wall_depth!r}"
        )
    names = list(MATERIALS)
    out_d, out_r = [], []
    yy, xx = torch.meshgrid(
        torch.arange(height, dtype=torch.float64),
        torch.arange(width, dtype=torch.float64),
        indexing="ij",
    )
    for b in range(batch):
        g = torch.Generator().manual_seed(seed + b)
        depth = torch.full((height, width), wd, dtype=torch.float64)
        refl = 0.6 + 0.05 * torch.cos(2 * math.pi * xx / 50.0)  # painted wall, slight texture
        for k, d in sorted(enumerate(ds), key=lambda t: -t[1]):
            frac = min(0.55, 0.35 * 2.0 / d + 0.1)
            bh, bw = int(frac * height * _u(g, 0.7, 1.0)), int(frac * width * _u(g, 0.6, 1.0))
            y0, x0 = int(_u(g, 0, height - bh)), int(_u(g, 0, width - bw))
            m = (yy >= y0) & (yy < y0 + bh) & (xx >= x0) & (xx < x0 + bw)
            kind = k % 4
            if kind == 3:  # checkerboard texture
                cell = max(4, bh // 6)
                chk = (torch.floor((yy - y0) / cell) + torch.floor((xx - x0) / cell)) % 2
                r = torch.where(chk > 0, 0.85, 0.05).to(torch.float64)
            elif kind == 2:  # colour stripes (different NIR reflectance per paint)
                r = 0.15 + 0.6 * (torch.floor((xx - x0) / max(3, bw // 8)) % 3) / 2
            else:
                r = torch.full_like(depth, MATERIALS[names[int(_u(g, 0, len(names) - 1e-9))]])
            depth = torch.where(m, torch.full_like(depth, d), depth)
            refl = torch.where(m, r, refl)
        out_d.append(depth)
        out_r.append(refl.clamp(0.01, 1.0))
    depth = torch.stack(out_d)[:, None]
    refl = torch.stack(out_r)[:, None]
    amp = K.LOW_SENSING_THRESHOLD * refl / depth**2
    return Scene(
        depth=depth.to(device=device, dtype=dtype),
        reflectance=refl.to(device=device, dtype=dtype),
        amplitude=amp.to(device=device, dtype=dtype),
    )
