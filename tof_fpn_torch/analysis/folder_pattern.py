r"""A camera's fixed pattern learned from its own frames of different scenes (torch only).

Every frame ``n`` of one camera carries the same fixed pattern ``p`` on top of its own scene:
``D_n = S_n + p + noise``. One frame cannot tell ``p`` from scene detail; frames of different
scenes can: a scene's detail (an edge, a kink, a staircase's steps, a flying pixel) sits in a
different place in each scene, the pattern in the same place in all. :func:`learn_fixed_pattern`

1. groups the frames into **distinct scenes**: two frames whose difference is noise alone
   (robust spread within :data:`STILL_RATIO` times the two frames' noise; the pattern cancels in
   the difference) are one scene, and are averaged; a still camera's frames are one scene, and
   fewer than :data:`MIN_SCENES` distinct scenes teach nothing (the result says so);
2. removes each scene's shape by its local least-squares plane over ``window`` x ``window``
   pixels (invalid pixels left out; linear in the frame, so a plane is removed exactly, at
   borders and holes too, and the pattern does not mix with the scene), refitted without the
   pixels far from it (:data:`CLIP` robust sigmas: the other side of a step or a kink, a flying
   pixel), which are then left out of the pattern too: what is left holds the pattern's part finer than the window, the noise and the
   scene's fine detail (edges, kinks);
3. takes, pixel by pixel, the **median over the distinct scenes**: detail that is in one scene's
   residual and not in the others' does not survive it;
4. splits the result into column, row and pixel parts and **confirms each on held-out scenes**:
   the same estimate from the even and from the odd scenes, ``a`` and ``b``, must agree with a
   significance ``z = <a, b> / (sqrt(n) s^2)`` (``s^2 = mean((a - b)^2) / 2``: the estimates'
   noise, in which a common pattern cancels) of at least ``z`` (default
   :data:`Z_CONFIRM`), and the part is then scaled by the cross-validated positive-part
   James-Stein factor ``clamp(<a, b> / <x, x>, 0, 1)`` (``x`` the estimate from all scenes): a
   part that the held-out halves do not confirm is left out, and nothing is changed when no part
   is confirmed.

What it cannot learn: patterns slower than the window (confounded with every scene's shape); a
pattern whose depth effect scales with the amplitude (a complex read-out offset, eq. (10) of
Georgiev et al. 2015) beyond its mean over the frames; anything from one scene.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch
import torch.nn.functional as F

from ..runtime.noise import estimate_sigma
from ..runtime.validity import valid_mask
from .calibrate import FixedPattern

__all__ = [
    "CLIP",
    "MIN_SCENES",
    "ROBUST_PASSES",
    "STILL_RATIO",
    "WINDOW",
    "Z_CONFIRM",
    "LearnedPattern",
    "distinct_scenes",
    "learn_fixed_pattern",
]

#: fewest distinct scenes a pattern is learned from (two halves of at least two each)
MIN_SCENES: int = 4
#: two frames are one scene when the robust spread of their difference is within this factor of
#: the noise of a difference of two frames of one scene
STILL_RATIO: float = 2.0
#: the local plane's window that models a scene's shape (pixels)
WINDOW: int = 21
#: the significance with which the held-out halves must agree on a part of the pattern
Z_CONFIRM: float = 4.0
#: a scene's pixel further than this many robust sigmas from its local plane is left out of the
#: plane (the other side of an edge) and of the pattern
CLIP: float = 3.0
#: refits of each scene's local plane without its outliers
ROBUST_PASSES: int = 2


@dataclass
class LearnedPattern:
    """What :func:`learn_fixed_pattern` found.

    Attributes:
        pattern: the confirmed pattern (column, row and pixel parts, metres), or None when no
            part was confirmed.
        frames: frames given; scenes: distinct scenes among them.
        parts: per part (``columns``, ``rows``, ``pixels``): ``z`` (held-out agreement),
            ``factor`` (the shrinkage applied, 0: left out) and ``rms_mm`` (after shrinkage).
        reason: one line: what was learned, or why nothing was.
    """

    pattern: FixedPattern | None
    frames: int
    scenes: int
    parts: dict = field(default_factory=dict)
    reason: str = ""


def _noise(depth: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """(N,) per-frame noise (wavelet MAD), floored at 1e-6 of the frame's depth scale."""
    s = estimate_sigma(torch.where(valid, depth, torch.zeros_like(depth)), valid)[:, 0]
    return s.clamp_min(1e-9)


def distinct_scenes(depth: torch.Tensor, valid: torch.Tensor, ratio: float = STILL_RATIO):
    """Group (N, 1, H, W) frames into scenes (module docstring, step 1): a list of lists of frame
    indices, in order of first appearance."""
    sigma = _noise(depth, valid)
    groups: list[list[int]] = []
    for n in range(depth.shape[0]):
        for g in groups:
            m = g[0]
            both = valid[n, 0] & valid[m, 0]
            if int(both.sum()) < 16:
                continue
            d = (depth[n, 0] - depth[m, 0])[both]
            spread = 1.4826 * (d - d.median()).abs().median()
            if spread <= ratio * math.hypot(float(sigma[n]), float(sigma[m])):
                g.append(n)
                break
        else:
            groups.append([n])
    return groups


def _box(t: torch.Tensor, window: int) -> torch.Tensor:
    """Sums of (H, W) ``t`` over ``window`` x ``window`` (zero outside), by cumulative sums."""
    pad = window // 2
    c = F.pad(t, (pad + 1, pad, pad + 1, pad)).cumsum(0).cumsum(1)
    return c[window:, window:] - c[:-window, window:] - c[window:, :-window] + c[:-window, :-window]


def _local_plane(x: torch.Tensor, window: int) -> torch.Tensor:
    """(H, W) the least-squares plane through the finite values of (H, W) ``x`` in the
    ``window`` x ``window`` around each pixel, at the pixel (normalised convolution; the local
    mean where a plane is not determined; NaN where a window holds nothing). Linear in ``x``: a
    plane comes out as itself, at borders and holes too, and a pattern's part finer than the
    window stays in ``x`` minus the plane."""
    h, w = x.shape
    ok = torch.isfinite(x).to(torch.float64)
    z = torch.where(torch.isfinite(x), x, torch.zeros_like(x)).to(torch.float64)
    yy, xx = torch.meshgrid(
        torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64), indexing="ij"
    )
    s = {k: _box(v, window) for k, v in {
        "1": ok, "y": ok * yy, "x": ok * xx, "yy": ok * yy * yy, "xx": ok * xx * xx,
        "xy": ok * xx * yy, "z": z, "yz": yy * z, "xz": xx * z,
    }.items()}  # fmt: skip
    n = s["1"]
    # moments about each pixel: sum (Y - i) = S_y - i S_1, ...
    su, sv = s["y"] - yy * n, s["x"] - xx * n
    suu = s["yy"] - 2 * yy * s["y"] + yy * yy * n
    svv = s["xx"] - 2 * xx * s["x"] + xx * xx * n
    suv = s["xy"] - yy * s["x"] - xx * s["y"] + xx * yy * n
    sz, suz, svz = s["z"], s["yz"] - yy * s["z"], s["xz"] - xx * s["z"]
    a = torch.stack([
        torch.stack([n, su, sv], -1), torch.stack([su, suu, suv], -1),
        torch.stack([sv, suv, svv], -1),
    ], -2)  # fmt: skip
    rhs = torch.stack([sz, suz, svz], -1)[..., None]
    det = torch.linalg.det(a)
    solvable = det > 1e-9 * n.clamp_min(1) ** 3
    eye = torch.eye(3, dtype=torch.float64)
    sol = torch.linalg.solve(torch.where(solvable[..., None, None], a, eye), rhs)[..., 0, 0]
    mean = sz / n.clamp_min(1)
    out = torch.where(solvable, sol, mean)
    return torch.where(n > 0, out, torch.full_like(out, math.nan)).to(x.dtype)


def _robust_residual(m: torch.Tensor, window: int, passes: int = ROBUST_PASSES) -> torch.Tensor:
    """(H, W) a scene minus its local plane fitted on its own side of every edge: the plane is
    refitted without the pixels further than :data:`CLIP` robust sigmas from the last fit (the
    other side of a step, a kink's far wall, a flying pixel), which are NaN in the result."""
    keep = torch.isfinite(m)
    nan = torch.full_like(m, math.nan)
    r = m - _local_plane(m, window)
    for _ in range(passes):
        centre = torch.nanmedian(r)
        scale = 1.4826 * torch.nanmedian((r - centre).abs())
        keep = torch.isfinite(m) & ((r - centre).abs() <= CLIP * scale)
        r = m - _local_plane(torch.where(keep, m, nan), window)
    return torch.where(keep, r, nan)


def _residuals(means: torch.Tensor, window: int) -> torch.Tensor:
    """(K, H, W) each scene's robust residual (:func:`_robust_residual`; NaN where the scene is
    invalid or an outlier)."""
    return torch.stack([_robust_residual(m, window) for m in means])


def _parts(p: torch.Tensor) -> dict[str, torch.Tensor]:
    """Column, row and pixel parts of an (H, W) map with NaN holes (robust: medians)."""
    c = torch.nanmedian(p, dim=0).values.nan_to_num(0.0)  # (W,)
    c = c - c.mean()
    r = torch.nanmedian(p - c[None, :], dim=1).values.nan_to_num(0.0)  # (H,)
    r = r - r.mean()
    q = (p - c[None, :] - r[:, None]).nan_to_num(0.0)
    return {"columns": c, "rows": r, "pixels": q}


def _agreement(a: torch.Tensor, b: torch.Tensor) -> float:
    """``<a, b>`` in standard deviations of its value without a common pattern: the noise of
    each estimate from the halves' difference (``var = mean((a - b)^2) / 2``: a pattern common
    to both cancels in it), ``sd0 = sqrt(n) var``."""
    n = a.numel()
    var = float((a - b).square().mean()) / 2.0
    num = float((a * b).sum())
    if var <= 0:
        return math.inf if num > 0 else 0.0
    return num / (math.sqrt(n) * var)


def learn_fixed_pattern(
    depth: torch.Tensor,
    amplitude: torch.Tensor | None = None,
    window: int = WINDOW,
    z: float = Z_CONFIRM,
    min_scenes: int = MIN_SCENES,
) -> LearnedPattern:
    """A camera's fixed pattern from its frames of different scenes (module docstring).

    Args:
        depth: (N, 1, H, W) frames of one camera, metres; invalid pixels by the package's rule.
        amplitude: (N, 1, H, W) or None (extends the validity rule).
        window: the local plane's window (odd, >= 3).
        z: the held-out agreement a part needs (> 0).
        min_scenes: fewest distinct scenes (>= 2).

    Returns:
        :class:`LearnedPattern` (``pattern`` None when nothing was confirmed, with the reason).

    Raises:
        ValueError: bad shapes or arguments (the message says what is allowed).

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> cols = 0.004 * torch.randn(48, generator=g)             # a camera's column offsets
        >>> y, x = torch.meshgrid(torch.arange(40.0), torch.arange(48.0), indexing="ij")
        >>> scenes = [2.0 + 0.01 * k * x + 0.02 * k * y for k in range(6)]   # six slanted walls
        >>> d = torch.stack([s + cols + 0.001 * torch.randn(40, 48, generator=g) for s in scenes])
        >>> found = learn_fixed_pattern(d[:, None])
        >>> found.scenes, found.parts["columns"]["factor"] > 0.9, found.parts["rows"]["factor"]
        (6, True, 0.0)
        >>> err = d - torch.stack(scenes) - found.pattern.offset_map().float()
        >>> round(1e3 * float((err - err.mean()).std()), 1)   # mm: 4.0 before, the noise 1.0
        1.4
    """
    if not isinstance(depth, torch.Tensor) or depth.dim() != 4 or depth.shape[1] != 1:
        raise ValueError(
            f"depth must be a (N, 1, H, W) tensor, got {getattr(depth, 'shape', depth)}"
        )
    if amplitude is not None and amplitude.shape != depth.shape:
        raise ValueError(f"amplitude must have depth's shape {list(depth.shape)}")
    if isinstance(window, bool) or not isinstance(window, int) or window < 3 or window % 2 == 0:
        raise ValueError(f"window must be an odd int >= 3, got {window!r}")
    if not (isinstance(z, (int, float)) and 0 < z < math.inf):
        raise ValueError(f"z must be a finite number > 0, got {z!r}")
    if isinstance(min_scenes, bool) or not isinstance(min_scenes, int) or min_scenes < 2:
        raise ValueError(f"min_scenes must be an int >= 2, got {min_scenes!r}")
    n = int(depth.shape[0])
    x = depth.detach().double()
    valid = valid_mask(x, None if amplitude is None else amplitude.detach().double())
    if min(x.shape[-2:]) < window:
        return LearnedPattern(None, n, 0, reason=f"frames smaller than the {window} px window")
    groups = distinct_scenes(x, valid)
    k = len(groups)
    if k < min_scenes:
        still = "a still scene: " if k == 1 and n > 1 else ""
        return LearnedPattern(
            None, n, k,
            reason=f"{still}{k} distinct scene(s) in {n} frame(s), at least {min_scenes} needed",
        )  # fmt: skip
    nan = torch.full_like(x, math.nan)
    xs = torch.where(valid, x, nan)[:, 0]
    means = torch.stack([torch.nanmean(xs[g], dim=0) for g in groups])  # (K, H, W)
    res = _residuals(means, window)
    full = _parts(torch.nanmedian(res, dim=0).values)
    half_a = _parts(torch.nanmedian(res[0::2], dim=0).values)
    half_b = _parts(torch.nanmedian(res[1::2], dim=0).values)
    parts, kept = {}, {}
    for name, est in full.items():
        a, b = half_a[name], half_b[name]
        agree = _agreement(a, b)
        energy = float((est * est).sum())
        factor = 0.0
        if agree >= z and energy > 0:
            factor = min(max(float((a * b).sum()) / energy, 0.0), 1.0)
        kept[name] = factor * est
        rms = 1e3 * float(kept[name].square().mean().sqrt())
        parts[name] = {"z": round(agree, 3), "factor": round(factor, 4), "rms_mm": round(rms, 4)}
    if all(p["factor"] == 0.0 for p in parts.values()):
        return LearnedPattern(
            None, n, k, parts,
            reason=f"no part confirmed by the held-out scenes (z >= {z:g}) in {k} scenes",
        )  # fmt: skip
    pattern = FixedPattern(
        column_offset=kept["columns"],
        row_offset=kept["rows"],
        pixel_offset=kept["pixels"] if parts["pixels"]["factor"] > 0 else None,
        frames=n,
        width=window,
    )
    found = ", ".join(f"{p} {v['rms_mm']:.2f} mm" for p, v in parts.items() if v["factor"] > 0)
    return LearnedPattern(pattern, n, k, parts, reason=f"learned from {k} scenes: {found}")
