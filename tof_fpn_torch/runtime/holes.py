r"""Invalid pixels and isolated outliers in the FPN filter (torch only, TorchScript-clean).

:class:`~tof_fpn_torch.runtime.FPNFilter` filters along one axis at a time. Along that axis, on every
line (a row for ``dim=-1``, a column for ``dim=-2``):

1. **Usable pixels** are the valid ones (:func:`~tof_fpn_torch.runtime.valid_mask` and the
   caller's ``mask``) that are not **isolated outliers**: a valid pixel more than
   :func:`outlier_ratio` (3) times as far as each valid neighbour at distance 1 on the line, or
   less than a third as far as each of them (a 3.6 m return on a 0.35 m wall), **next to an
   invalid pixel** (in its 3 x 3 neighbourhood: where a camera's own invalidation leaves stray
   returns, such as flying pixels at the edge of a hole) and alone there (a thin object, a bar one
   pixel wide or a spoke, is a run of such pixels across the lines, and is filtered as the scene
   it is). Away from holes nothing is an outlier: a frame without invalid pixels is filtered as
   a plain FIR. A pixel without a valid neighbour on the line is not an outlier either. The rule
   is scale-free (metres or millimetres give the same pixels).
2. **The output at a usable pixel** ``n`` is the filter applied to the line in which every pixel
   that is not usable is replaced by ``x_n``, the pixel's own depth:

       y_n = sum_{k usable} h_k x_{n-k} + (sum_{k not usable} h_k) x_n,

   i.e. the weight of the taps that fall on holes and outliers goes to the pixel itself. It is
   computed as two FIRs with the fast kernel, of the zero-filled depth ``x0`` and of the
   indicator ``u`` of the pixels that are not usable: ``y = h * x0 + (h * u) x0``. The borders pad
   ``u`` like the depth (``zeros``: outside counts as a usable 0, as without holes).
3. Every pixel that is not usable gets its input back (invalid ones bit for bit, outliers
   unchanged); a usable pixel whose output would not be a valid depth keeps its input too.

**The bound.** With ``c`` the pixel's own tap (index ``L // 2``) and ``H(0) = sum h``,
``y_n - H(0) x_n = sum_{k usable} h_k (x_{n-k} - x_n)``, so

    |y_n - x_n| <= (sum_{k != c} |h_k|) * max |x_m - x_n| + |H(0) - 1| * |x_n|,

the maximum over the usable pixels ``m`` within the filter's support around ``n``: **a valid pixel
moves by at most** ``sum_{k != c} |h_k|`` **(1.13 for the default ``{20, 0.14}`` design) times the
largest difference between its depth and a usable depth the filter reaches** (plus ``|H(0) - 1|
|x_n|``, 0 for unit-DC designs). An outlier or a hole moves none of its neighbours; no depth from
across a hole enters. ``tests/test_fpn_holes.py`` checks the rule against SciPy and the bound on
synthetic frames and on the real ADTF3175 wall.

Why this rule: it needs no fill values (a second FIR instead, at the kernel's speed), it never
divides (the plain normalised convolution ``h * x0 / h * (1 - u)`` does, and the notch taps'
negative lobes let that denominator fall to 0.3, or below 0 for the 42-tap design, amplifying the
noise), it is exact on constant depth, and its bound stays within the filter's support.
"""

from __future__ import annotations

import torch
from torch.nn import functional as F

from .fir import _phases, fir_last, fir_operators, fir_polyphase
from .validity import valid_mask

__all__ = [
    "certified",
    "holed_exact",
    "holed_lines",
    "isolated_outliers",
    "outlier_ratio",
    "tap_gains",
]


def outlier_ratio() -> float:
    """How many times deeper (or shallower) than each neighbour an isolated outlier is."""
    return 3.0


def _pad1(t: torch.Tensor) -> torch.Tensor:
    """One zero column on each side (cat, not F.pad: exports to opset 17)."""
    z = t.new_zeros(t.shape[0], 1)
    return torch.cat([z, t, z], 1)


def isolated_outliers(x0: torch.Tensor, v: torch.Tensor, lines: int = 0) -> torch.Tensor:
    """Step 1's outliers: (R, W) bool, True where a valid pixel is more than :func:`outlier_ratio`
    times as far as each valid neighbour at distance 1 along the last axis, or less than its
    inverse times as far as each, next to an invalid pixel (in its 3 x 3 neighbourhood of the
    image; without ``lines``, on the line), and alone: no other pixel of that neighbourhood is
    such a pixel (a thin object, a bar 1 px wide or a spoke, is a run of them across the lines,
    filtered as the scene it is).

    Args:
        x0: (R, W) depth, 0 where invalid (no NaN / inf).
        v: (R, W) 1.0 where valid, 0.0 elsewhere.
        lines: lines per image (the rows of ``x0`` are ``R / lines`` images of ``lines`` lines
            each); 0: lines are not neighbours (each is tested alone).
    """
    xp = _pad1(x0)
    far = torch.maximum(xp[:, :-2], xp[:, 2:])  # deepest valid neighbour (0: none)
    inv = v / (x0 + (1.0 - v))  # 1 / depth where valid, 0 elsewhere
    ip = _pad1(inv)
    near = torch.maximum(ip[:, :-2], ip[:, 2:])  # 1 / the nearest valid neighbour (0: none)
    ratio = outlier_ratio()
    deep = (x0 > ratio * far) & (far > 0)
    shallow = (inv > ratio * near) & (near > 0)
    odd = deep | shallow
    r, w = odd.shape[0], odd.shape[1]
    if lines > 0 and r % lines == 0:
        f = odd.to(x0.dtype).view(r // lines, 1, lines, w)
        others = F.avg_pool2d(f, 3, 1, 1, False, True) * 9.0 - f  # the others flagged in 3 x 3
        hole = F.max_pool2d((1.0 - v).view(r // lines, 1, lines, w), 3, 1, 1)  # invalid in 3 x 3
        return odd & (others.view(r, w) < 0.5) & (hole.view(r, w) > 0.5)
    vp = _pad1(v) + torch.cat([v[:, :1], v.new_zeros(r, w), v[:, -1:]], 1)  # borders: valid
    return odd & (torch.minimum(vp[:, :-2], vp[:, 2:]) < 0.5)  # an invalid neighbour on the line


def certified(lo: float, hi: float, gains: tuple[float, float], border: str) -> bool:
    """Every FIR output of inputs in [lo, hi] is valid: ``sum h+ lo - sum |h-| hi`` stays above the
    float rounding of the sums, and the largest output is finite (``zeros`` borders add inputs 0)."""
    pos, neg = gains
    if border == "zeros":
        lo = 0.0
    margin = 1e-4 * (pos + neg) * hi
    return pos * lo - neg * hi > margin and (pos + neg) * hi < 1e37


def tap_gains(taps: torch.Tensor) -> tuple[float, float]:
    """(sum of the positive taps, sum of |the negative taps|)."""
    t = taps.detach()
    return float(t.clamp_min(0.0).sum()), float(-t.clamp_max(0.0).sum())


def _chunk_samples() -> int:
    """Samples per chunk of :func:`holed_lines` (a function: TorchScript reads no globals)."""
    return 1 << 18


def holed_lines(
    x2: torch.Tensor,
    valid2: torch.Tensor | None,
    taps: torch.Tensor,
    border: str,
    ops: list[torch.Tensor],
    gains: tuple[float, float],
    top: float,
    lines: int = 0,
) -> torch.Tensor:
    """Inference: the rule on (R, W) lines, in chunks of :func:`_chunk_samples` (their temporaries
    stay in the cache). ``valid2``: the valid pixels, or None when they are all the others than the
    +0.0 ones (maybe all), ``top`` then the largest depth; ``lines``: lines per image (for the
    outliers' neighbourhood). Outliers are searched only when a chunk's depths span more than a
    factor 3 (elsewhere there can be none), then over all lines at once (they look across lines)."""
    r, w = x2.shape[0], x2.shape[1]
    out = torch.empty_like(x2)
    rows = max(1, _chunk_samples() // w)
    exact_codes = valid2 is None  # every unusable value is finite and not -0.0: lerp is exact
    # the polyphase kernel straight away (fir_last's checks once per call, not per chunk)
    direct = x2.dtype == torch.float32 and x2.device.type == "cpu" and w >= taps.shape[0]
    direct = direct and 2 * min(rows, r) * w >= 2 * _phases()
    g = taps.flip(0).to(device=x2.device, dtype=x2.dtype)
    if direct and len(ops) == 0:
        ops = fir_operators(taps, border)
    odd_all: torch.Tensor | None = None  # the outliers of every line, found when first needed
    for r0 in range(0, r, rows):
        r1 = min(r, r0 + rows)
        xc = x2[r0:r1]
        both = torch.empty((2, r1 - r0, w), dtype=x2.dtype, device=x2.device)
        x0, u = both[0], both[1]  # zero-filled depth, not-usable indicator: one FIR for both
        peak = top
        if valid2 is not None:
            vb = valid2[r0:r1]
            torch.where(vb, xc, torch.zeros_like(xc), out=x0)
            u.copy_(~vb)
            peak = float(x0.amax())
        else:
            x0.copy_(xc)
            torch.le(xc, 0.0, out=u)
        lo, hi = torch.aminmax(torch.addcmul(x0, u, torch.full_like(x0[:1, :1], peak)))
        if not bool(hi < outlier_ratio() * lo):  # else no line of the chunk can hold an outlier
            if odd_all is None:  # they look across lines, maybe into other chunks: all at once
                vall = (x2 > 0) if valid2 is None else valid2
                x0all = torch.where(vall, x2, torch.zeros_like(x2))
                odd_all = isolated_outliers(x0all, vall.to(x2.dtype), lines)
            odd = odd_all[r0:r1]
            if bool(odd.any()):
                u.masked_fill_(odd, 1.0)
                x0.masked_fill_(odd, 0.0)
                lo, hi = torch.aminmax(torch.addcmul(x0, u, torch.full_like(x0[:1, :1], peak)))
        if direct and 2 * (r1 - r0) * w >= 2 * _phases():
            y2 = fir_polyphase(both.view(-1, w), g, border, ops)
        else:
            y2 = fir_last(both.view(-1, w), taps, border, ops, True)
        y = y2[: r1 - r0].addcmul_(y2[r1 - r0 :], x0)
        oc = out[r0:r1]
        if exact_codes:
            torch.lerp(y, xc, u, out=oc)
        else:
            torch.where(u > 0, xc, y, out=oc)
        if not certified(float(lo), float(hi), gains, border):  # a valid pixel stays valid
            oc.copy_(torch.where((u < 1) & ~valid_mask(oc), xc, oc))
    return out


def holed_exact(
    x2: torch.Tensor,
    valid2: torch.Tensor,
    taps: torch.Tensor,
    border: str,
    ops: list[torch.Tensor],
    fast: bool,
    lines: int = 0,
) -> torch.Tensor:
    """The same rule branch-free and out of place (tracing for export, autograd)."""
    x0 = torch.where(valid2, x2, torch.zeros_like(x2))
    usable = valid2 & ~isolated_outliers(x0, valid2.to(x2.dtype), lines)
    u = (~usable).to(x2.dtype)
    x0 = torch.where(usable, x0, torch.zeros_like(x0))
    y = fir_last(x0, taps, border, ops, fast) + fir_last(u, taps, border, ops, fast) * x0
    out = torch.where(usable, y, x2)
    return torch.where(valid2 & ~valid_mask(out), x2, out)
