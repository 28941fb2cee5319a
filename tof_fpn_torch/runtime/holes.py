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
   computed as two FIRs, of the zero-filled depth ``x0`` and of the indicator ``u`` of the
   pixels that are not usable: ``y = h * x0 + (h * u) x0``. The borders pad ``u`` like the depth
   (``zeros``: outside counts as a usable 0, as without holes). NaN, 0 and the other codes of
   invalid pixels take the same path: each chunk of lines replaces them by 0 once.
3. Every pixel that is not usable gets its input back (invalid ones bit for bit, except that a
   signalling NaN comes back as the quiet NaN of the same payload; outliers unchanged); a usable
   pixel whose output would not be a valid depth keeps its input too.

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

from .fir import _in_phases, _phases, fir_last, fir_operators, pad_index
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
    """Samples per chunk and thread of :func:`holed_lines` (a function: TorchScript reads no
    globals): a thread's share of the chunk's depth and indicator, padded, and of their filtered
    copies stays in its core's L2 cache, and every operation on a chunk is one parallel region."""
    return 1 << 17


def _big() -> float:
    """Stands in for an unusable pixel in the chunk's minimum (above every finite float32)."""
    return 3.0e38


def holed_lines(
    x2: torch.Tensor,
    valid2: torch.Tensor | None,
    taps: torch.Tensor,
    border: str,
    ops: list[torch.Tensor],
    gains: tuple[float, float],
    top: float,
    lines: int = 0,
    zeros: bool = True,
) -> torch.Tensor:
    """Inference: the rule on (R, W) lines, in chunks of about :func:`_chunk_samples` samples.

    ``valid2``: the caller's mask joined with the validity rule, or None: then ``zeros`` says the
    invalid values are all ``+0.0`` (``top``: the largest depth), else they may be any code (NaN,
    +-inf, <= 0), replaced per chunk by one ``nan_to_num`` (no NaN arithmetic after it; negative
    codes, ``-0.0`` and the infinities, seen by one min / max, are cleared too and take an exact
    bitwise write-back). ``lines``: lines per image (the outliers' neighbourhood).

    Per chunk, the zero-filled depth ``x0`` and the indicator ``u`` of the pixels that are not
    usable are written once into one buffer; on CPU float32 each line is written there with its
    border padding around it (slices of it), so one polyphase convolution of the whole buffer gives
    both FIRs with no row border to redo. Then ``y = h * x0 + (h * u) x0`` and the write-back:
    ``lerp`` to the input where ``u`` is 1 (exact for finite codes; a NaN keeps its sign and
    payload). Outliers are searched only when a chunk's usable depths span more than a factor 3
    (elsewhere there can be none), then over all lines at once (they look across lines).
    """
    r, w = x2.shape[0], x2.shape[1]
    out = torch.empty_like(x2)
    length = taps.shape[0]
    right = length // 2
    left = length - 1 - right
    q_out, p_in = _phases(), _in_phases()
    direct = x2.dtype == torch.float32 and x2.device.type == "cpu" and length > 1
    direct = direct and r * (w + left + right) >= 2 * q_out  # the kernel's smallest input
    wp = w + left + right if direct else w  # a padded line in the buffer
    per = _chunk_samples()
    if not torch.jit.is_scripting():  # each thread works on its share of the chunk
        per *= max(1, torch.get_num_threads())
    rows = min(r, max(1, per // wp))
    seg = ((rows * wp + p_in - 1) // p_in) * p_in
    if direct and len(ops) == 0:
        ops = fir_operators(taps, border)
    # one buffer per call, [x0 | u], and one for the chunk's temporaries
    buf = torch.zeros(2 * seg if direct else 2 * rows * w, dtype=x2.dtype, device=x2.device)
    tmp = torch.empty(rows * wp, dtype=x2.dtype, device=x2.device)
    src_left = torch.zeros(0, dtype=torch.long, device=x2.device)
    src_right = torch.zeros(0, dtype=torch.long, device=x2.device)
    if direct and border != "zeros":
        idx, _ = pad_index(w, left, right, border, x2.device)
        src_left, src_right = idx[:left] + left, idx[left + w :] + left
    weight = ops[0].to(x2.device) if direct else buf[:0]
    bits = not torch.jit.is_scripting()  # int32 views of float32 (TorchScript reads them as shapes)
    bits = bits and x2.dtype == torch.float32
    cpu = x2.device.type == "cpu"
    zero = torch.zeros((1, 1), dtype=x2.dtype, device=x2.device)
    odd_all: torch.Tensor | None = None  # the outliers of every line, found when first needed
    rc, sc = 0, 0
    pair, x0, u, x0f, uf, tf = buf, buf, buf, buf, buf, buf
    for r0 in range(0, r, rows):
        r1 = min(r, r0 + rows)
        xc = x2[r0:r1]
        if r1 - r0 != rc:  # the views of the buffer (the same for every chunk but the last)
            rc = r1 - r0
            sc = ((rc * wp + p_in - 1) // p_in) * p_in if direct else rc * w
            pair = buf[: 2 * sc].view(2, sc)[:, : rc * wp].view(2, rc, wp)
            both = pair[:, :, left : left + w] if direct else pair
            x0, u = both[0], both[1]
            x0f, uf = buf[: rc * wp], buf[sc : sc + rc * wp]  # the lines with their padding
            tf = tmp[: rc * wp]
        # 1. the zero-filled depth x0 (NaN and infinities replaced once), padded like the lines
        hi = top
        signed = False  # x0 holds negative codes or -0.0 (only with other codes than +0.0)
        if valid2 is not None:
            torch.where(valid2[r0:r1], xc, zero, out=x0)
        elif zeros:
            x0.copy_(xc)
        else:
            torch.nan_to_num(xc, 0.0, -1.0, -1.0, out=x0)  # infinities: see below
        if direct:
            _pad_lines(pair[:1], left, right, w, border, src_left, src_right)
        if valid2 is not None:
            hi = float(x0f.amax())
        elif not zeros:
            if bits:  # the sign bit shows negative codes, -0.0 and the infinities (now -1)
                ext = torch.aminmax(x0f.view(torch.int32))
                signed = bool(ext[0] < 0)
                hi = float(torch.stack([ext[0], ext[1]]).view(torch.float32)[1])
            else:
                ext = torch.aminmax(x0f)
                signed = bool(ext[0] < 0)
                hi = float(ext[1])
            if signed:  # every invalid x0 exactly +0.0 (-0.0 + 0.0 is +0.0)
                x0f.clamp_min_(0.0).add_(0.0)
                hi = max(hi, 0.0)
        # 2. the indicator u and the usable depths' minimum: outliers possible? outputs valid?
        torch.le(x0f, 0.0, out=uf)  # the padding too (zeros: 1 there, for the minimum)
        lo = float(torch.add(x0f, uf, alpha=_big(), out=tf).amin())
        if direct and border == "zeros":
            _pad_lines(pair[1:], left, right, w, border, src_left, src_right)
        if not bool(hi < outlier_ratio() * lo):  # else no line of the chunk can hold an outlier
            if odd_all is None:  # they look across lines, maybe into other chunks: all at once
                vall = valid_mask(x2) if valid2 is None else valid2
                x0all = torch.where(vall, x2, torch.zeros_like(x2))
                odd_all = isolated_outliers(x0all, vall.to(x2.dtype), lines)
            odd = odd_all[r0:r1]
            if bool(odd.any()):
                u.masked_fill_(odd, 1.0)
                x0.masked_fill_(odd, 0.0)
                if direct:
                    _pad_lines(pair, left, right, w, border, src_left, src_right)
                lo = float(torch.add(x0f, uf, alpha=_big(), out=tf).amin())
                hi = float(x0f.amax())
        # 3. both FIRs at once
        if direct:
            yb = _padded_fir(buf[: 2 * sc], weight, left)
            fb = yb.view(2, sc)[:, : rc * wp].view(2, rc, wp)[:, :, left : left + w]
        else:
            fb = fir_last(pair.view(-1, w), taps, border, ops, True).view(2, rc, w)
        y = fb[0].addcmul_(fb[1], x0)
        # 4. the write-back: every unusable pixel gets its input back
        oc = out[r0:r1]
        if valid2 is not None or not bits:
            torch.where(u > 0.0, xc, y, out=oc)
        elif not signed and (zeros or cpu):  # +0.0 codes, outliers; NaN codes' sign and payload
            torch.lerp(y, xc, u, out=oc)  # are kept on CPU (a signalling NaN comes back quiet)
        else:  # y zeroed there, OR the input's own bits in: xc ^ x0 (x0 is +0.0 there)
            y.addcmul_(y, u, value=-1.0)
            t = tmp[: rc * w].view(rc, w).view(torch.int32)
            torch.bitwise_xor(xc.view(torch.int32), x0.view(torch.int32), out=t)
            torch.bitwise_or(y.view(torch.int32), t, out=oc.view(torch.int32))
        if not certified(lo, hi, gains, border):  # a valid pixel stays valid
            oc.copy_(torch.where(valid_mask(oc), oc, xc))
    return out


def _pad_lines(
    pair: torch.Tensor,
    left: int,
    right: int,
    w: int,
    border: str,
    src_left: torch.Tensor,
    src_right: torch.Tensor,
) -> None:
    """Write the border padding of every line of ``pair`` (..., left + w + right) from its middle
    ``w`` samples: slices where the line is long enough, the gathers of ``src_*`` otherwise."""
    if border == "zeros":  # outside is a usable 0 (the layout moves with the chunk: rewrite)
        pair[:, :, :left] = 0.0
        pair[:, :, left + w :] = 0.0
    elif border == "reflect" and w > max(left, right):
        pair[:, :, :left] = pair[:, :, left + 1 : 2 * left + 1].flip(2)
        pair[:, :, left + w :] = pair[:, :, left + w - 1 - right : left + w - 1].flip(2)
    elif border == "replicate":
        pair[:, :, :left] = pair[:, :, left : left + 1]
        pair[:, :, left + w :] = pair[:, :, left + w - 1 : left + w]
    elif border == "circular" and w >= max(left, right):
        pair[:, :, :left] = pair[:, :, w : w + left]
        pair[:, :, left + w :] = pair[:, :, left : left + right]
    else:
        pair[:, :, :left] = pair.index_select(2, src_left)
        pair[:, :, left + w :] = pair.index_select(2, src_right)


def _padded_fir(flat: torch.Tensor, weight: torch.Tensor, left: int) -> torch.Tensor:
    """The correlation of a flat float32 signal whose length is a multiple of 8 with the polyphase
    ``weight`` (:func:`~tof_fpn_torch.runtime.fir.polyphase_weight`), output ``i`` aligned with
    input ``i`` (``convolve1d`` centring); outputs whose window leaves the signal are not
    meaningful (each line in :func:`holed_lines` carries its own padding)."""
    q_out, p_in = _phases(), _in_phases()
    stride = q_out // p_in
    n = flat.shape[0]
    m = n // p_in
    k_len = weight.shape[-1]
    pad = (left + p_in - 1) // p_in
    while ((m + 2 * pad - k_len) // stride + 1) * q_out < pad * p_in - left + n:
        pad += 1
    xi = flat.view(1, 1, m, p_in).permute(0, 3, 1, 2)
    y = F.conv2d(xi, weight, stride=(1, stride), padding=(0, pad))
    start = pad * p_in - left
    return y.permute(0, 2, 3, 1).reshape(-1)[start : start + n]


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
