"""The non-local means kernel: one pass per search offset over the whole batch (torch only).

The integral-image (box-filter) formulation of Darbon et al. (ISBI 2008). Pairs are symmetric
(``w(p, t) = w(p + t, -t)``), so only half of the offsets are computed and each weight map is
accumulated twice. The box filter is separable and runs as shifted adds on flat buffers (rows of the
flat buffer hold garbage in the last ``s - 1`` columns, never read), weights use ``exp2`` with the
scale folded into the input, and every intermediate lives in buffers allocated once per call
(in-place ops): the run time is dominated by memory traffic, not by Python. The formulas are in
:mod:`tof_fpn_torch.denoise.nlm`. Literals kept here: ``-100.0`` (log2 of the smallest weight,
``2**-100`` keeps every value a normal float32) and ``1e-30`` (floor of noise variances).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from .. import constants as K

__all__ = ["nlm_core", "patch_taps", "reflect_pad"]


def reflect_pad(x: torch.Tensor, pad: int) -> torch.Tensor:
    """``numpy.pad(mode='reflect')`` of the last two axes for any ``pad`` (repeated reflection;
    an axis of length 1 is replicated)."""
    for axis in [3, 2]:
        rem = pad
        while rem > 0:
            n = x.shape[axis]
            p = rem if n == 1 else min(rem, n - 1)
            spec = [p, p, 0, 0] if axis == 3 else [0, 0, p, p]
            x = F.pad(x, spec, mode="replicate" if n == 1 else "reflect")
            rem -= p
    return x


def patch_taps(s: int, kernel: str) -> list[float]:
    """1-D patch weights summing to ``s`` (so both kernels weigh a constant patch as ``s^2``):
    empty for the box (plain sums); for ``'gaussian'`` skimage's ``fast_mode=False`` kernel
    ``exp(-u^2 / (2 a^2))``, ``a = (s - 1) / 4`` (separable)."""
    if kernel == "box" or s == 1:
        return []
    a = (s - 1) / 4.0
    g = [math.exp(-float((j - s // 2) ** 2) / (2.0 * a * a)) for j in range(s)]
    total = sum(g)
    return [s * v / total for v in g]


def _box_flat(
    src: torch.Tensor,
    n_out: int,
    s: int,
    step: int,
    t1: torch.Tensor,
    t2: torch.Tensor,
    out: torch.Tensor,
    taps: list[float],
) -> torch.Tensor:
    """``out[i] = sum_{j < s} c_j src[i + j * step]`` for ``i < n_out`` (1-D). Box (``taps``
    empty, ``c_j = 1``) by binary doubling: ``s = 7`` takes 4 adds; else one op per tap.
    ``t1``/``t2`` are scratch buffers at least as long as ``src``."""
    if len(taps) > 0:
        o = out[:n_out]
        torch.mul(src[:n_out], taps[0], out=o)
        for j in range(1, s):
            o.add_(src[j * step : j * step + n_out], alpha=taps[j])
        return o
    parts: list[torch.Tensor] = []
    starts: list[int] = []
    block = src
    span = 1
    rem = s
    pos = 0
    flip = True
    while rem > 0:
        if rem % 2 == 1:
            parts.append(block)
            starts.append(pos)
            pos += span
        rem = rem // 2
        if rem > 0:
            m = block.shape[0] - span * step
            buf = t1 if flip else t2
            flip = not flip
            nb = buf[:m]
            torch.add(block[:m], block[span * step : span * step + m], out=nb)
            block = nb
            span *= 2
    o = out[:n_out]
    if len(parts) == 1:
        o.copy_(parts[0][starts[0] * step : starts[0] * step + n_out])
    else:
        a0 = starts[0] * step
        a1 = starts[1] * step
        torch.add(parts[0][a0 : a0 + n_out], parts[1][a1 : a1 + n_out], out=o)
        for i in range(2, len(parts)):
            a = starts[i] * step
            o.add_(parts[i][a : a + n_out])
    return o


def _offsets(d: int) -> list[tuple[int, int]]:
    """Half of the search window without 0: ``t_x > 0``, or ``t_x = 0`` and ``t_y > 0``."""
    out: list[tuple[int, int]] = []
    for ty in range(-d, d + 1):
        for tx in range(1, d + 1):
            out.append((ty, tx))
    for ty in range(1, d + 1):
        out.append((ty, 0))
    return out


def _patch_noise(
    hvp: torch.Tensor, vpp: torch.Tensor | None, s: int, taps: list[float]
) -> torch.Tensor:
    """(B, 1, H + 2d, W + 2d) patch mean ``V`` of ``sigma^2 / 2`` (padded ``hvp``), over the valid
    pixels ``vpp`` (padded 0/1, or None: all), with the patch weights ``taps`` (box if empty)."""
    g1 = torch.tensor(taps if len(taps) > 0 else [1.0] * s, dtype=hvp.dtype, device=hvp.device)
    g1 = g1 / s
    g2 = torch.outer(g1, g1).reshape(1, 1, s, s)
    if vpp is None:
        vbar = F.conv2d(hvp, g2)
    else:
        vbar = F.conv2d(hvp * vpp, g2) / F.conv2d(vpp, g2).clamp_min(1e-6)
    return vbar.clamp_min(1e-30)


def nlm_core(
    x: torch.Tensor,
    valid: torch.Tensor | None,
    scale: torch.Tensor,
    half_var: torch.Tensor | None,
    s: int,
    d: int,
    h: float,
    taps: list[float],
) -> torch.Tensor:
    """NLM of one batch chunk with patch ``taps`` (:func:`patch_taps`). ``x`` (B, C, H, W)
    float32/64, zero where invalid; ``valid`` (B, 1, H, W) 0/1 in the dtype of ``x`` or None
    (all valid); ``scale`` (B, 1, 1, 1) folds ``sqrt(log2 e) / (h sigma sqrt(C))`` (and ``1 / s``
    without mask) into the input; ``half_var`` (B, 1, H, W) ``sigma^2 / 2`` for the noise-map
    path, else None.

    Every per-offset op is a 1-D op on the flat padded grid (row stride ``Wp``, image stride
    ``Hp * Wp``): the shifted copy of the padded image is a flat slice, and the columns and rows
    that fall outside an offset's region hold garbage that is never read.

    The loop over the offsets cannot be split: it is the TorchScript kernel's hot loop, and its
    nine flat workspaces (allocated once, outside it) are re-viewed per offset as slices and
    strided views of one another; a helper per step would take them all, and the offsets'
    region arithmetic, as some twenty arguments."""
    B, C, H, W = x.shape
    r = s // 2
    E = d + r
    dt = x.dtype
    dev = x.device
    bias = 2.0 * K.LOG2_E / (h * h)
    fold = valid is None and half_var is None
    cb = torch.full([], bias / (s * s) if fold else bias, dtype=dt, device=dev)
    xp = reflect_pad(x * scale, E).contiguous()  # (B, C, Hp, Wp)
    Hp = xp.shape[2]
    Wp = xp.shape[3]
    plane = Hp * Wp
    xpf = xp.reshape(-1)
    vals = x if valid is None else x * valid
    xvp = reflect_pad(vals, d)
    num = vals.clone()
    den = torch.ones_like(x[:, :1]) if valid is None else valid.clone()
    vpf = torch.empty(0, dtype=dt, device=dev)
    vdp = torch.empty(0, dtype=dt, device=dev)
    if valid is not None:
        vpf = reflect_pad(valid, E).contiguous().reshape(-1)
        vdp = reflect_pad(valid, d)
    vbar = torch.empty(0, dtype=dt, device=dev)
    if half_var is not None:
        vpp = None if valid is None else vpf.view(B, 1, Hp, Wp)
        vbar = _patch_noise(reflect_pad(half_var, E), vpp, s, taps)

    diff = torch.empty(B * C * plane, dtype=dt, device=dev)
    n1 = B * plane
    sq = torch.empty(n1, dtype=dt, device=dev)
    t1 = torch.empty(n1, dtype=dt, device=dev)
    t2 = torch.empty(n1, dtype=dt, device=dev)
    hb = torch.empty(n1, dtype=dt, device=dev)
    wb = torch.empty(n1, dtype=dt, device=dev)
    mm = torch.empty(n1 if valid is not None else 0, dtype=dt, device=dev)
    nb = torch.empty(n1 if valid is not None else 0, dtype=dt, device=dev)
    s2 = torch.empty(B * (H + d) * (W + d) if half_var is not None else 0, dtype=dt, device=dev)

    for ty, tx in _offsets(d):
        y0 = min(0, -ty)  # weight region: rows [y0, y0 + hr), cols [-tx, W) in image coords
        x0 = -tx
        hr = H + abs(ty)
        wr = W + tx
        hh = hr + 2 * r
        a0 = (E + y0 - r) * Wp + (E + x0 - r)  # flat start of the patch pixels of p
        b0 = a0 + ty * Wp + tx  # ... and of p + t
        tail = (hh - 1) * Wp + wr + 2 * r  # flat extent of one image's region
        n = (B - 1) * plane + tail
        nc = (B * C - 1) * plane + tail
        dff = diff[:nc]
        torch.sub(xpf[a0 : a0 + nc], xpf[b0 : b0 + nc], out=dff)
        if valid is not None:
            mmf = mm[:n]
            torch.mul(vpf[a0 : a0 + n], vpf[b0 : b0 + n], out=mmf)
            if C == 1:
                dff.mul_(mmf)
            else:
                dv = diff[: B * C * plane].view(B, C, plane)[:, :, :tail]
                dv.mul_(mm[: B * plane].view(B, 1, plane)[:, :, :tail])
        sqf = sq[:n]
        if C == 1:
            if fold:
                torch.addcmul(cb, dff, dff, value=-1.0, out=sqf)
            else:
                torch.mul(dff, dff, out=sqf)
        else:
            dff.mul_(dff)
            torch.sum(
                diff[: B * C * plane].view(B, C, plane)[:, :, :tail],
                1,
                out=sq[: B * plane].view(B, plane)[:, :tail],
            )
            if fold:
                torch.add(cb, sqf, alpha=-1.0, out=sqf)
        # separable patch sums: the box/taps along a row, then along a column (step Wp)
        nh = n - (s - 1)
        nv = nh - (s - 1) * Wp
        _box_flat(sqf, nh, s, 1, t1, t2, hb, taps)
        if len(taps) == 0:  # along columns one strided sum beats the doubling adds
            wf = wb[:nv]
            torch.sum(hb.as_strided([nv, s], [1, Wp]), 1, out=wf)
        else:
            wf = _box_flat(hb, nv, s, Wp, t1, t2, wb, taps)
        wv = wb.as_strided([B, 1, hr, wr], [plane, plane, Wp, 1])
        if valid is not None:
            _box_flat(mm[:n], nh, s, 1, t1, t2, hb, taps)
            nf = _box_flat(hb, nv, s, Wp, t1, t2, nb, taps)
            wf.div_(nf.clamp_(min=1.0))
        if half_var is not None:
            s2v = s2[: B * hr * wr].view(B, 1, hr, wr)
            vy = d + y0
            vx = d + x0
            torch.add(
                vbar[:, :, vy : vy + hr, vx : vx + wr],
                vbar[:, :, vy + ty : vy + ty + hr, vx + tx : vx + tx + wr],
                out=s2v,
            )
            wv.div_(s2v)
        if not fold:
            torch.add(cb, wf, alpha=-1.0, out=wf)
        wf.clamp_(-100.0, 0.0).exp2_()
        # pair (p, p + t): w at p weighs x(p + t), and at p + t weighs x(p)
        wd = wv[:, :, -y0 : -y0 + H, -x0 : -x0 + W]
        ws = wv[:, :, -y0 - ty : -y0 - ty + H, -x0 - tx : -x0 - tx + W]
        num.addcmul_(wd, xvp[:, :, d + ty : d + ty + H, d + tx : d + tx + W])
        num.addcmul_(ws, xvp[:, :, d - ty : d - ty + H, d - tx : d - tx + W])
        if valid is None:
            den.add_(wd)
            den.add_(ws)
        else:
            den.addcmul_(wd, vdp[:, :, d + ty : d + ty + H, d + tx : d + tx + W])
            den.addcmul_(ws, vdp[:, :, d - ty : d - ty + H, d - tx : d - tx + W])
    return num / den
