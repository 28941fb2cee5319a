r"""Flying (mixed) pixels at depth edges: detection, a confidence map, and what to do with them
(torch only; TorchScript and ONNX exportable).

A pixel whose footprint straddles a depth edge sums the returns of both surfaces. The phasors add,
so its depth lies **between** the two surfaces and its amplitude is that of a mixture (at most the
brighter side's): a point floating in the air between foreground and background. A slanted
surface also has depths between its neighbours; what tells them apart is that a slope is a
surface: a plane fitted beside the pixel, extrapolated to it, predicts it. A mixed pixel is
predicted by no surface around it.

**Noise.** ``sigma``: the law ``sigma^2 = e^c A^-gamma`` of
:func:`~tof_fpn_torch.runtime.noise.facet_noise` (fitted per frame to 3 x 3 plane residuals; one
level without an amplitude), raised where the data are locally noisier than the law to the root
of the mean of the 3 x 3 residual variances over the :data:`LOCAL` (7) x 7 window around the
pixel, each clipped at :data:`LOCAL_CLIP` (2) times the law's variance (so the windows across an
edge add little).

**The rule.** A valid pixel ``p`` with depth ``d`` is **flying** when both hold:

1. *No surface predicts it.* Facets are least-squares planes through the :data:`FACET` (5) x 5
   windows centred 3 and 4 pixels from ``p`` in the 8 directions (16 facets, :mod:`._facets`); a
   narrower window fits a 3-pixel ramp through a mixed pixel as well as it fits a surface. A facet
   is a **surface** when its residual variance is at most :data:`FACET_FIT` (3) times ``sigma^2``
   at its centre (a window across an edge is not a plane and fails). ``z_s = min |d - P_f| /
   u_f`` over the surfaces ``f``, ``P_f`` the plane extrapolated to ``p``, ``u_f = sigma_f sqrt(1
   + 1/N + r^2/M)`` the standard deviation of ``d - P_f`` (``r`` the offset, ``M`` the window's
   second moment). Where no facet has all its pixels valid (holes, frame borders) the pixel is
   never flagged.
2. *It lies between two sides.* Along one of the 4 lines through ``p`` (horizontal, vertical,
   diagonal), a pixel within :data:`REACH` (4) on one side is nearer than ``d`` and one on the
   other side is farther, each by ``z_b`` times ``sqrt((sigma_p^2 + sigma_q^2) / 2)``, and ``d``
   lies at least :data:`SHARE` (3 %) of the way from the nearest depth of the one side to the
   farthest of the other, and from that to this (a pixel at 1 % of a 2 m step is on its surface,
   e.g. the border column of a 3-pixel bar; 5 % kept more such columns and missed more mixed
   pixels). ``z_b`` is the largest such margin over the lines.
   With an amplitude, a line counts only where ``A_p <= (1 + tolerance) max A_q`` over its pixels
   (:data:`AMPLITUDE_TOLERANCE`; a mixture is not brighter than its brighter surface).

``q = min(z_s, z_b)``; the pixel is flagged when ``q > threshold`` (:data:`THRESHOLD`, 2.25). The
**confidence** is ``clamp((threshold + softness - q) / (2 softness), 0, 1)``: 1 for a pixel a
surface explains, 0 for a clear mixed pixel, 0.5 at the threshold (a valid pixel is flagged iff
its confidence is < 0.5), 0 at invalid pixels; a network can take it as an input channel.

An object thinner than the window (a bar 1-3 px wide, a cable) is nearer than both sides of it,
not between them, so it is kept; the mixed pixels at its border are flagged like any other.

**Actions.** ``"mark"`` returns the depth unchanged (the confidence is the product),
``"invalidate"`` writes ``fill`` (0: the usual "no measurement" code; NaN works too) into flagged
pixels, ``"reassign"`` gives each flagged pixel the depth of the kept pixel within
:data:`REASSIGN_RADIUS` (2) whose depth is nearest to its own (the surface that dominates the
mixture; ``fill`` where there is none). Invalid input pixels are returned bit for bit in every
mode.

The constants were chosen on simulated scenes (``benchmarks/bench_flying.py``, its tuning seeds);
how the rule differs from the camera SDKs' (libfreenect2, the ADI SDK, Open3D): docs/flying.md.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from ._checks import check_image, check_same_shape, check_tensor_type
from ._facets import local_noise, nearest_kept, shifted, window_fit, window_variance
from .noise import facet_noise
from .stage import RecordField, Setting, Stage
from .validity import valid_mask

__all__ = [
    "ACTIONS",
    "AMPLITUDE_TOLERANCE",
    "FACET",
    "FACET_FIT",
    "LOCAL",
    "LOCAL_CLIP",
    "REACH",
    "REASSIGN_RADIUS",
    "RULE",
    "SHARE",
    "THRESHOLD",
    "FlyingPixels",
    "flying_pixels",
]

#: what :func:`flying_pixels` does with a flagged pixel
ACTIONS: tuple[str, ...] = ("mark", "invalidate", "reassign")
#: a facet is a surface when its residual variance is at most this times the noise variance
FACET_FIT: float = 3.0
#: pixels on each side of a line that the "between" test looks at
REACH: int = 4
#: a mixture's amplitude may exceed its brighter side's by this fraction (noise) and still count
AMPLITUDE_TOLERANCE: float = 0.1
#: a pixel is between two sides when at least this share of their depth gap from each
SHARE: float = 0.03
#: noise sigmas a pixel must be off every surface and between two sides by to be flagged
THRESHOLD: float = 2.25
#: side of the window of the local noise level (pixels)
LOCAL: int = 7
#: facet residual variances above this times the law's count as this in the local level
LOCAL_CLIP: float = 2.0
#: side of the facet windows (pixels)
FACET: int = 5
#: a reassigned pixel takes the depth of a kept pixel at most this far (a square)
REASSIGN_RADIUS: int = 2
#: the constants as the functions take them (TorchScript reads no module globals)
RULE: tuple[float, float, float, float, int, int, int, int] = (
    FACET_FIT,
    AMPLITUDE_TOLERANCE,
    SHARE,
    LOCAL_CLIP,
    REACH,
    FACET,
    REASSIGN_RADIUS,
    LOCAL,
)


def _support(
    x: torch.Tensor,
    sigma: torch.Tensor,
    fit: tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor],
    facet_fit: float,
    size: int,
) -> torch.Tensor:
    """``z_s``: the smallest distance of ``x`` to a surface facet's extrapolation in units of its
    standard deviation (inf where no facet is a surface; -inf where no facet has all its pixels
    valid, so no test applies). Facets: ``size`` x ``size`` (5) windows centred 3 and 4 pixels
    away in the 8 directions (a narrower window fits a 3-pixel ramp through a mixed pixel as well
    as it fits a surface); ``fit``: their :func:`._facets.window_fit` on the frame padded by 4. A
    facet that is no surface gets the mean -inf, so its distance is inf (no NaN to skip)."""
    m, gx, gy, v = fit
    pad = 4
    sp = F.pad(sigma, (pad, pad, pad, pad), value=1.0)
    surface = v <= facet_fit * sp * sp  # NaN (a window off the valid pixels): False
    fp = v >= 0.0  # all its pixels valid (v is NaN otherwise)
    mp = torch.where(surface, m, torch.full_like(m, -math.inf))
    gxp = torch.nan_to_num(gx, nan=0.0)
    gyp = torch.nan_to_num(gy, nan=0.0)
    inv = 1.0 / sp
    count = float(size * size)
    moment = float(size * sum([k * k for k in range(-(size // 2), size // 2 + 1)]))
    z_s = torch.full_like(x, math.inf)
    seen = torch.zeros_like(x, dtype=torch.bool)
    for diagonal in [False, True]:
        for dist in [3, 4]:
            r2 = float(2 * dist * dist) if diagonal else float(dist * dist)
            w = inv * (1.0 / math.sqrt(1.0 + 1.0 / count + r2 / moment))
            lines = [(1, 1), (1, -1)] if diagonal else [(0, 1), (1, 0)]
            for uy, ux in lines:
                for sign in [-1, 1]:
                    oy = sign * dist * uy
                    ox = sign * dist * ux
                    z = x - shifted(mp, oy, ox, pad)  # x - P_f = x - m + oy g_y + ox g_x
                    if oy != 0:
                        z.add_(shifted(gyp, oy, ox, pad), alpha=oy)
                    if ox != 0:
                        z.add_(shifted(gxp, oy, ox, pad), alpha=ox)
                    z_s.clamp_max_(z.abs_().mul_(shifted(w, oy, ox, pad)))
                    seen.logical_or_(shifted(fp, oy, ox, pad))
    return torch.where(seen, z_s, torch.full_like(x, -math.inf))


def _between(
    x: torch.Tensor,
    sigma: torch.Tensor,
    amplitude: torch.Tensor | None,
    tolerance: float,
    reach: int,
    share: float,
) -> torch.Tensor:
    """``z_b``: the largest margin (noise units) by which ``x`` lies between the two sides of one
    of the 4 lines through it (-inf where it lies between none), looking ``reach`` pixels out; a
    line counts where ``x`` is at least ``share`` of the way from each side's extreme to the
    other's.

    The normalised difference ``E = (x_r - x_q) / sqrt(h_r + h_q)`` of each pixel ``r`` and its
    neighbour ``q = r + k u`` is computed once on the padded frame and read at ``p`` (side b) and
    at ``p - k u`` (side a). An absent pixel (invalid or off the frame) is ``+inf`` in one copy of
    the frame and ``-inf`` in the other (its ``E`` is the first copy's with the infinities
    swapped), so each maximum and minimum skips it without a mask. A condition ``c > 0`` applies
    to a margin ``z`` as ``min(z, c * inf)`` with NaN (``c`` zero or undefined) read as -inf.
    Temporaries are worked on in place where they can be."""
    pad = reach
    inf = math.inf
    rows, cols = x.shape[-2], x.shape[-1]
    xp = F.pad(x, (pad, pad, pad, pad), value=float("nan"))
    lo_p = torch.nan_to_num(xp, nan=inf, posinf=inf, neginf=-inf)  # absent: never the nearest
    hi_p = torch.nan_to_num(xp, nan=-inf, posinf=inf, neginf=-inf)  # nor the farthest
    h2 = 0.5 * sigma * sigma
    h2p = F.pad(h2, (pad, pad, pad, pad), value=1.0)
    ap: torch.Tensor | None = None
    if amplitude is not None:
        a = F.pad(amplitude, (pad, pad, pad, pad), value=0.0)
        ap = torch.nan_to_num(a.clamp_min(0.0), nan=0.0)  # absent or <= 0: 0
    z_b = x  # (placeholder for TorchScript)
    for line, (uy, ux) in enumerate([(0, 1), (1, 0), (1, 1), (1, -1)]):
        # the extremes of E over k: at p (side b) and at p - k u (side a)
        max_b, min_b, max_a, min_a = x, x, x, x  # (placeholders for TorchScript)
        for k in range(1, reach + 1):
            oy, ox = k * uy, k * ux
            y0, x0 = max(0, -oy), max(0, -ox)  # E on every r with r and r + k u in the padding
            h = xp.shape[-2] - abs(oy)
            w = xp.shape[-1] - abs(ox)
            s = (_win(h2p, y0, x0, h, w) + _win(h2p, y0 + oy, x0 + ox, h, w)).sqrt_()
            e_lo = (_win(lo_p, y0, x0, h, w) - _win(lo_p, y0 + oy, x0 + ox, h, w)).div_(s)
            # E of the other copy: the same numbers, the infinities (an absent pixel) swapped
            e_hi = torch.nan_to_num(e_lo, nan=math.nan, posinf=-inf, neginf=inf)
            by, bx = pad - y0, pad - x0  # p in E
            ay, ax = by - oy, bx - ox  # p - k u in E
            lo_b, hi_b = _win(e_lo, by, bx, rows, cols), _win(e_hi, by, bx, rows, cols)
            lo_a, hi_a = _win(e_lo, ay, ax, rows, cols), _win(e_hi, ay, ax, rows, cols)
            if k == 1:
                max_b, min_b, max_a, min_a = lo_b, hi_b, hi_a, lo_a
            elif k == 2:
                max_b, min_b = torch.maximum(max_b, lo_b), torch.minimum(min_b, hi_b)
                max_a, min_a = torch.maximum(max_a, hi_a), torch.minimum(min_a, lo_a)
            else:
                max_b.clamp_min_(lo_b)
                min_b.clamp_max_(hi_b)
                max_a.clamp_min_(hi_a)
                min_a.clamp_max_(lo_a)
        # nearer than side b by -min_b and farther than side a by -min_a, or the other way round
        # (in place unless reach is 1: then max_b and min_a are views of the same E)
        z_ba = max_b.clamp_max_(max_a) if reach > 1 else torch.minimum(max_b, max_a)
        z_ab = min_a.clamp_min_(min_b).neg_()
        near_a, near_b = _reach_extreme(lo_p, uy, ux, reach, False)
        far_a, far_b = _reach_extreme(hi_p, uy, ux, reach, True)
        z = _one_way(x, z_ab, near_a, far_b, share)
        z.clamp_min_(_one_way(x, z_ba, near_b, far_a, share))
        if amplitude is not None and ap is not None:
            bright_a, bright_b = _reach_extreme(ap, uy, ux, reach, True)
            both = torch.maximum(bright_a, bright_b)
            # A <= (1 + tolerance) max A_q: sign(d) + 0.5 > 0 iff d >= 0, and never 0
            mixture = both.mul_(1.0 + tolerance).sub_(amplitude).sign_().add_(0.5)
            z.clamp_max_(mixture.mul_(inf))
        if line == 0:
            z_b = z
        else:
            z_b.clamp_min_(z)
    return z_b


def _win(t: torch.Tensor, y: int, x: int, h: int, w: int) -> torch.Tensor:
    """The ``h`` x ``w`` window of ``t`` from row ``y``, column ``x`` (a view)."""
    return t[:, :, y : y + h, x : x + w]


def _reach_extreme(
    padded: torch.Tensor, uy: int, ux: int, reach: int, largest: bool
) -> tuple[torch.Tensor, torch.Tensor]:
    """``(side a, side b)``: the largest (``largest``) or smallest value of ``padded`` (a frame
    padded by ``reach``, no NaN) at ``-k (uy, ux)`` and at ``k (uy, ux)`` from every pixel, ``k =
    1 .. reach``. Both are views of one map of the extremes of ``reach`` consecutive pixels along
    the line, built by doubling (2 passes for ``reach`` 4)."""
    rows = padded.shape[-2] - 2 * reach
    cols = padded.shape[-1] - 2 * reach
    out = padded
    width = 1
    while width < reach:
        step = min(width, reach - width)
        h = out.shape[-2] - step * abs(uy)
        w = out.shape[-1] - step * abs(ux)
        # out'[i] = extreme of out[i] and out[i + step u] (a negative component shifts the origin)
        first = _win(out, step if uy < 0 else 0, step if ux < 0 else 0, h, w)
        second = _win(out, step if uy > 0 else 0, step if ux > 0 else 0, h, w)
        out = torch.maximum(first, second) if largest else torch.minimum(first, second)
        width += step
    # out[i] = extreme of padded[i + o + k u], k = 0 .. reach - 1; o: the origin of out
    oy = 0 if uy >= 0 else reach - 1
    ox = 0 if ux >= 0 else reach - 1
    side_a = _win(out, reach - reach * uy - oy, reach - reach * ux - ox, rows, cols)
    side_b = _win(out, reach + uy - oy, reach + ux - ox, rows, cols)
    return side_a, side_b


def _one_way(
    x: torch.Tensor, z: torch.Tensor, near: torch.Tensor, far: torch.Tensor, share: float
) -> torch.Tensor:
    """``z`` (the margin by which ``x`` is farther than one side and nearer than the other; worked
    on in place) where ``x`` lies ``share`` of the way from ``near`` (one side's nearest depth) and
    from ``far`` (the other's farthest), -inf elsewhere."""
    if share > 0.0:
        gap = (far - near).mul_(share)
        # x - near > gap and far - x > gap: the smaller difference > 0 (NaN where a side is absent)
        inside = (x - near).sub_(gap).clamp_max_((far - x).sub_(gap))
        z = z.clamp_max_(inside.mul_(math.inf)).nan_to_num_(
            nan=-math.inf, posinf=math.inf, neginf=-math.inf
        )
    return z


@torch.jit.unused
def _check(action: str, threshold: float, softness: float, min_noise: float) -> None:
    if action not in ACTIONS:
        raise ValueError(f"action must be one of {list(ACTIONS)}, got {action!r}")
    for name, value in (("threshold", threshold), ("softness", softness), ("min_noise", min_noise)):
        if not (value > 0.0 and value < math.inf):
            raise ValueError(f"{name} must be a finite number > 0, got {value!r}")


def _flying(
    depth: torch.Tensor,
    amplitude: torch.Tensor | None,
    action: str,
    threshold: float,
    fill: float,
    min_noise: float,
    softness: float,
    rule: tuple[float, float, float, float, int, int, int, int],
) -> tuple[torch.Tensor, torch.Tensor]:
    facet_fit, tolerance, share, clip, reach, size, radius, local = rule
    check_image(depth, "depth", 1)
    if amplitude is not None:
        check_image(amplitude, "amplitude", 1)
        check_same_shape(amplitude, depth, "amplitude", "depth")
    work = torch.float64 if depth.dtype == torch.float64 else torch.float32
    d = depth.to(work)
    valid = valid_mask(d, None if amplitude is None else amplitude.to(work))
    x = torch.where(valid, d, torch.full_like(d, math.nan))
    amp: torch.Tensor | None = None
    if amplitude is not None:
        amp = torch.where(valid, amplitude.to(work), torch.full_like(d, math.nan))
    pad = 4 + size // 2  # facets centred up to 4 px off the frame
    xp = F.pad(x, (pad, pad, pad, pad), value=float("nan"))
    v3 = window_variance(xp, pad, 3, 0)
    sigma = local_noise(v3, facet_noise(x, amp, min_noise, residuals=v3), local, clip)
    z_s = _support(x, sigma, window_fit(xp, pad, size, 4), facet_fit, size)
    z_b = _between(x, sigma, amp, tolerance, reach, share)
    q = z_s.clamp_max_(z_b)  # min(z_s, z_b)
    flagged = valid & (q > threshold)
    conf = q.neg_().add_(threshold + softness).div_(2.0 * softness).clamp_(0.0, 1.0)
    conf = torch.where(valid, conf, torch.zeros_like(conf))
    if action == "mark":
        return depth.clone(), conf.to(depth.dtype)
    new = torch.full_like(d, fill)
    if action == "reassign":
        target = nearest_kept(x, valid & ~flagged, radius)
        new = torch.where(torch.isfinite(target), target, new)
    return torch.where(flagged, new.to(depth.dtype), depth), conf.to(depth.dtype)


def flying_pixels(
    depth: torch.Tensor,
    amplitude: torch.Tensor | None = None,
    action: str = "mark",
    threshold: float = THRESHOLD,
    fill: float = 0.0,
    min_noise: float = 1e-3,
    softness: float = 1.0,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Detect flying (mixed) pixels and act on them (the rule: module docstring).

    Args:
        depth: (B, 1, H, W) float depth (metres for the default ``min_noise``); invalid pixels
            (:func:`~tof_fpn_torch.runtime.valid_mask`) are never used and come out bit for bit.
        amplitude: (B, 1, H, W) amplitude or None. With it the noise follows the amplitude law
            and the mixture test applies; without it the noise is one level per frame.
        action: ``"mark"`` (depth unchanged), ``"invalidate"`` (``fill`` at flagged pixels) or
            ``"reassign"`` (a flagged pixel takes the depth of the nearest-in-depth kept pixel
            within 2 px; ``fill`` where there is none).
        threshold: noise sigmas a pixel must be off every surface and between two sides by
            (:data:`THRESHOLD`).
        fill: the value of an invalidated pixel (0 or NaN: both read as invalid).
        min_noise: floor of the noise map, in depth units.
        softness: half-width of the confidence ramp around ``threshold``, in sigmas.

    Returns:
        ``(depth, confidence)``, both (B, 1, H, W) in the depth's dtype: the depth after the
        action and the confidence in [0, 1] (< 0.5 exactly where flagged, 0 at invalid pixels).

    Example:
        >>> d = torch.full((1, 1, 24, 24), 2.0)
        >>> d[..., 12:] = 1.0                       # a step edge 1 m deep
        >>> d[..., 11] = 1.5                        # one column of mixed pixels
        >>> d = d + 0.002 * torch.randn(1, 1, 24, 24, generator=torch.Generator().manual_seed(0))
        >>> out, conf = flying_pixels(d, action="invalidate")
        >>> int((out[0, 0, 6:18] == 0).sum()), int((conf < 0.5).sum())
        (12, 24)
    """
    if not torch.jit.is_scripting():
        check_tensor_type(depth, "depth")
        check_tensor_type(amplitude, "amplitude", optional=True)
        _check(action, threshold, softness, min_noise)
    return _flying(depth, amplitude, action, threshold, fill, min_noise, softness, RULE)


class FlyingPixels(Stage):
    """Flying-pixel stage: :func:`flying_pixels` with its settings held (module docstring).

    Args:
        action: ``"mark"``, ``"invalidate"`` or ``"reassign"``.
        threshold, fill, min_noise, softness: as in :func:`flying_pixels`.

    Shape:
        - depth: (B, 1, H, W) float; amplitude: (B, 1, H, W) or None.
        - :meth:`forward`: the depth after the action, (B, 1, H, W); :meth:`run`: the depth and
          the record ``flagged`` and ``valid`` (B,) pixel counts and ``confidence`` (B, 1, H, W).

    Example:
        >>> stage = FlyingPixels("reassign")
        >>> out, rec = stage.run(torch.full((2, 1, 32, 32), 1.5), torch.full((2, 1, 32, 32), 100.0))
        >>> bool((out == 1.5).all()), bool((rec["confidence"] == 1).all()), rec["flagged"].tolist()
        (True, True, [0.0, 0.0])
    """

    settings = (
        Setting("action", str, "mark", "what happens to a flagged pixel", choices=ACTIONS),
        Setting(
            "threshold",
            float,
            THRESHOLD,
            "noise sigmas off every surface that flag a pixel",
            low=0.0,
            open_low=True,
        ),
        Setting("fill", float, 0.0, "the depth of an invalidated pixel (0 or NaN: invalid)"),
        Setting(
            "min_noise", float, 1e-3, "floor of the noise map, depth units", low=0.0, open_low=True
        ),
        Setting(
            "softness",
            float,
            1.0,
            "half-width of the confidence ramp, sigmas",
            low=0.0,
            open_low=True,
        ),
    )
    record = (
        RecordField("flagged", "valid pixels flagged as flying (confidence < 0.5)"),
        RecordField("valid", "valid pixels the stage saw"),
        RecordField("confidence", "1: a surface explains the pixel, < 0.5: flagged", "pixel"),
    )
    #: :func:`~tof_fpn_torch.export.export_onnx` takes the TorchScript-based exporter (seconds;
    #: ``torch.export`` and the ONNX optimiser take minutes over the unrolled loops)
    onnx_dynamo = False

    def __init__(
        self,
        action: str = "mark",
        threshold: float = THRESHOLD,
        fill: float = 0.0,
        min_noise: float = 1e-3,
        softness: float = 1.0,
    ) -> None:
        super().__init__()
        _check(action, threshold, softness, min_noise)
        self.action = action
        self.threshold = float(threshold)
        self.fill = float(fill)
        self.min_noise = float(min_noise)
        self.softness = float(softness)
        self.rule = RULE

    def extra_repr(self) -> str:
        return (
            f"action={self.action!r}, threshold={self.threshold}, fill={self.fill}, "
            f"min_noise={self.min_noise}, softness={self.softness}"
        )

    def _run(
        self, depth: torch.Tensor, amplitude: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        out, conf = _flying(
            depth,
            amplitude,
            self.action,
            self.threshold,
            self.fill,
            self.min_noise,
            self.softness,
            self.rule,
        )
        valid = valid_mask(depth, amplitude)
        flagged = (conf < 0.5) & valid
        record = {
            "flagged": flagged.flatten(1).sum(1).to(torch.float32),
            "valid": valid.flatten(1).sum(1).to(torch.float32),
            "confidence": conf,
        }
        return out, record
