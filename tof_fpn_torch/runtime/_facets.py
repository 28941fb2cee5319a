r"""Local plane fits ("facets") of a depth map (torch only, TorchScript- and ONNX-clean).

A facet is the least-squares plane ``z = m + g_x x + g_y y`` through an ``h x w`` window
(``h``, ``w`` odd, ``x, y`` in pixels from its centre). With the window sums ``S = sum z``,
``S_x = sum x z``, ``S_y = sum y z`` and ``Q = sum z^2`` over its ``N = h w`` pixels,
``X = h sum x^2`` and ``Y = w sum y^2`` (``1``, ``x`` and ``y`` are orthogonal on a window
symmetric about its centre)::

    m = S / N,   g_x = S_x / X,   g_y = S_y / Y,
    v = (Q - N m^2 - X g_x^2 - Y g_y^2) / (N - 3)       (residual variance, N - 3 dof)

``m``, ``g_x``, ``g_y`` are convolutions of ``z`` (one ``conv2d`` call), ``v`` the sum of the
squared residuals over the window's pixels; a window touching an invalid pixel (NaN) gives NaN,
which every comparison downstream reads as False. The facet's value at an offset ``(dy, dx)`` from its centre is
``m + g_y dy + g_x dx``; its variance for i.i.d. noise of variance ``s^2`` is
``s^2 (1 / N + dy^2 / Y + dx^2 / X)``.

Also here, for the flying-pixel stage (:mod:`.flying`): :func:`window_fit` (the same fits from
float64 window sums of shifted adds, on a padded domain: several times faster than the
convolution and the per-pixel residual loop), :func:`local_noise` (the noise map raised to the
local level of the 3 x 3 facet residuals) and :func:`nearest_kept` (the depth a reassigned pixel
takes).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

__all__ = [
    "facet_sums",
    "local_noise",
    "nearest_kept",
    "plane_fit",
    "shifted",
    "window_fit",
    "window_variance",
]


def facet_sums(
    h: int, w: int, dtype: torch.dtype, device: torch.device
) -> tuple[torch.Tensor, float, float]:
    """``(kernels, X, Y)``: the (3, 1, h, w) kernels of ``S``, ``S_x``, ``S_y``, and ``X``, ``Y``."""
    px = torch.arange(-(w // 2), w // 2 + 1, dtype=dtype, device=device)
    py = torch.arange(-(h // 2), h // 2 + 1, dtype=dtype, device=device)
    ones = torch.ones(h, w, dtype=dtype, device=device)
    kx = px.view(1, w).expand(h, w)
    ky = py.view(h, 1).expand(h, w)
    kernels = torch.stack([ones, kx, ky]).reshape(3, 1, h, w)
    # X and Y in Python (no tensor read back: torch.export traces without a data-dependent value)
    sx = float(sum([k * k for k in range(-(w // 2), w // 2 + 1)]))
    sy = float(sum([k * k for k in range(-(h // 2), h // 2 + 1)]))
    return kernels, float(h) * sx, float(w) * sy


def plane_fit(
    z: torch.Tensor, h: int, w: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(m, g_x, g_y, v)`` of the ``h x w`` facet centred on every pixel of ``z`` (B, 1, H, W),
    each (B, 1, H, W); NaN where the window touches a NaN or leaves the image. ``v`` is the mean
    of the squared residuals over the window (``N - 3`` dof), summed pixel by pixel: from ``Q -
    N m^2`` it would cancel in float32 (the variance of 1 mm noise on 2 m is below the rounding of
    ``Q``)."""
    kernels, sxx, syy = facet_sums(h, w, z.dtype, z.device)
    ph, pw = h // 2, w // 2
    x = F.pad(z, (pw, pw, ph, ph), value=float("nan"))
    sums = F.conv2d(x, kernels)
    count = float(h * w)
    m = sums[:, 0:1] / count
    gx = sums[:, 1:2] / sxx
    gy = sums[:, 2:3] / syy
    v = torch.zeros_like(m)
    rows, cols = z.shape[-2], z.shape[-1]
    for dy in range(-ph, ph + 1):
        for dx in range(-pw, pw + 1):
            zq = x[:, :, ph + dy : ph + dy + rows, pw + dx : pw + dx + cols]
            r = zq - (m + gy * float(dy) + gx * float(dx))
            v = v + r * r
    return m, gx, gy, v / (count - 3.0)


def shifted(padded: torch.Tensor, dy: int, dx: int, pad: int) -> torch.Tensor:
    """The map at offset ``(dy, dx)`` from every pixel: a view of ``padded`` (a map padded by
    ``pad`` on every side; ``|dy|, |dx| <= pad``)."""
    h = padded.shape[-2] - 2 * pad
    w = padded.shape[-1] - 2 * pad
    return padded[:, :, pad + dy : pad + dy + h, pad + dx : pad + dx + w]


def window_fit(
    padded: torch.Tensor, pad: int, size: int, out: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(m, g_x, g_y, v)`` of :func:`plane_fit` for ``size`` x ``size`` windows (``size`` odd)
    centred on the pixels of the map padded by ``out`` (each (B, 1, H + 2 out, W + 2 out)), from
    ``padded``, the map padded by ``pad >= out + size // 2`` with NaN (:func:`_window_sums`).
    ``m`` and ``v`` are NaN where the window touches a NaN or leaves the image; ``g_x`` and ``g_y``
    can be numbers there (they skip the centre column and row). Returned in the dtype of
    ``padded``."""
    s, q, sx, sy = _window_sums(padded, pad, size, out)
    count, moment = float(size * size), _moment(size)
    m = s / count
    gx = sx / moment
    gy = sy / moment
    q.sub_(s * m).sub_(sx * gx).sub_(sy * gy).clamp_min_(0.0).div_(count - 3.0)
    dt = padded.dtype
    return m.to(dt), gx.to(dt), gy.to(dt), q.to(dt)


def window_variance(padded: torch.Tensor, pad: int, size: int, out: int) -> torch.Tensor:
    """``v`` of :func:`window_fit` alone."""
    s, q, sx, sy = _window_sums(padded, pad, size, out)
    count, moment = float(size * size), _moment(size)
    v = q.sub_(s * (s / count)).sub_(sx * (sx / moment)).sub_(sy * (sy / moment))
    return v.clamp_min_(0.0).div_(count - 3.0).to(padded.dtype)


def _moment(size: int) -> float:
    """``X = Y`` of a ``size`` x ``size`` window."""
    return float(size * sum([k * k for k in range(-(size // 2), size // 2 + 1)]))


def _window_sums(
    padded: torch.Tensor, pad: int, size: int, out: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(S, Q, S_x, S_y)`` in float64 of the windows of :func:`window_fit`: shifted adds, a row
    pass then a column pass. float64 keeps ``Q - S^2 / N`` exact to about 1e-9 of the noise
    variance (float32 would lose it to the rounding of ``Q``)."""
    h = size // 2
    rows = padded.shape[-2] - 2 * pad + 2 * out
    cols = padded.shape[-1] - 2 * pad + 2 * out
    c0 = pad - out - h  # the first row and column the windows touch
    z = padded[:, :, c0 : c0 + rows + 2 * h, c0 : c0 + cols + 2 * h].to(torch.float64)
    zz = z * z
    hs = _centred_sum(z, h, cols, 3)  # row pass: sums along x of z, z^2 and x z
    hq = _centred_sum(zz, h, cols, 3)
    hx = _moment_sum(z, h, cols, 3)
    s = _centred_sum(hs, h, rows, 2)  # column pass
    q = _centred_sum(hq, h, rows, 2)
    sx = _centred_sum(hx, h, rows, 2)
    sy = _moment_sum(hs, h, rows, 2)
    return s, q, sx, sy


def _centred_sum(t: torch.Tensor, h: int, n: int, dim: int) -> torch.Tensor:
    """``t[i + h] + sum_k (t[i + h - k] + t[i + h + k])``, ``k = 1 .. h``, along ``dim`` (length
    ``n``), added in this order."""
    out = t.narrow(dim, h, n).clone() if h == 0 else t.narrow(dim, h, n) + t.narrow(dim, h - 1, n)
    for k in range(1, h + 1):
        if k > 1:
            out.add_(t.narrow(dim, h - k, n))
        out.add_(t.narrow(dim, h + k, n))
    return out


def _moment_sum(t: torch.Tensor, h: int, n: int, dim: int) -> torch.Tensor:
    """``sum_k k (t[i + h + k] - t[i + h - k])``, ``k = 1 .. h``, along ``dim`` (length ``n``)."""
    out = t.narrow(dim, h + 1, n) - t.narrow(dim, h - 1, n)
    for k in range(2, h + 1):
        out.add_(t.narrow(dim, h + k, n), alpha=k).sub_(t.narrow(dim, h - k, n), alpha=k)
    return out


def local_noise(v: torch.Tensor, law: torch.Tensor, size: int, clip: float) -> torch.Tensor:
    """The noise map raised to the local level where the data are noisier than the law: the root
    of the mean over a ``size`` x ``size`` window of the 3 x 3 facet residual variances ``v``
    (NaN where a window is not valid), each clipped at ``clip`` times the law's variance (a window
    across an edge counts as that)."""
    cap = clip * law * law
    vc = torch.minimum(v, cap)
    ok = (vc * 0.0).add_(1.0).nan_to_num_(nan=0.0)  # 1 where v is a number, else 0
    pad = size // 2
    both = F.pad(torch.cat([vc.nan_to_num_(nan=0.0), ok], 1), (pad, pad, pad, pad))
    box = _box_sum(_box_sum(both, size, 3), size, 2)
    local = torch.sqrt(box[:, 0:1] / box[:, 1:2].clamp_min(1.0))
    return torch.maximum(law, local)


def _box_sum(t: torch.Tensor, size: int, dim: int) -> torch.Tensor:
    """Sums of ``size`` consecutive values of ``t`` along ``dim`` (the length shrinks by ``size -
    1``) from the sums of 1, 2, 4, ... values (doubling): 3 passes for 5 values, 4 for 7."""
    n = t.shape[dim] - size + 1
    parts = [t]  # parts[j]: sums of 2^j consecutive values
    while (1 << len(parts)) <= size:
        last, width = parts[-1], 1 << (len(parts) - 1)
        m = last.shape[dim] - width
        parts.append(last.narrow(dim, 0, m) + last.narrow(dim, width, m))
    pieces: list[torch.Tensor] = []
    done = 0
    for j in range(len(parts) - 1, -1, -1):
        if size & (1 << j):
            pieces.append(parts[j].narrow(dim, done, n))
            done += 1 << j
    if len(pieces) == 1:
        return pieces[0].clone()
    out = pieces[0] + pieces[1]
    for piece in pieces[2:]:
        out.add_(piece)
    return out


def nearest_kept(x: torch.Tensor, keep: torch.Tensor, radius: int) -> torch.Tensor:
    """The depth of the kept pixel within ``radius`` (a square) whose depth is nearest to ``x``
    (NaN where there is none): the surface a mixed pixel is mostly made of."""
    xp = F.pad(
        torch.where(keep, x, torch.full_like(x, math.nan)),
        (radius, radius, radius, radius),
        value=float("nan"),
    )
    best = torch.full_like(x, math.inf)
    target = torch.full_like(x, math.nan)
    for dy in range(-radius, radius + 1):
        for dx in range(-radius, radius + 1):
            q = shifted(xp, dy, dx, radius)
            err = (x - q).abs()
            better = err < best  # NaN (not kept) compares False
            best = torch.where(better, err, best)
            target = torch.where(better, q, target)
    return target
