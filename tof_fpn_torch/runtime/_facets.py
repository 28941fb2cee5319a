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

__all__ = ["facet_sums", "local_noise", "nearest_kept", "plane_fit", "shifted", "window_fit"]


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
    ``padded``, the map padded by ``pad >= out + size // 2`` with NaN. The window sums are
    in-place shifted adds in float64 (a row pass, then a column pass) and ``v = (Q - S^2 / N -
    S_x^2 / X - S_y^2 / Y) / (N - 3)``: float64 keeps the difference exact to about 1e-9 of the
    noise variance. Returned in the dtype of ``padded``."""
    h = size // 2
    rows = padded.shape[-2] - 2 * pad + 2 * out
    cols = padded.shape[-1] - 2 * pad + 2 * out
    c0 = pad - out - h  # the first row and column the windows touch
    z = padded[:, :, c0 : c0 + rows + 2 * h, c0 : c0 + cols + 2 * h].to(torch.float64)
    zz = z * z
    # row pass: sums along x of z, z^2 and x z
    hs = z[:, :, :, h : h + cols].clone()
    hq = zz[:, :, :, h : h + cols].clone()
    hx = torch.zeros_like(hs)
    for k in range(1, h + 1):
        left, right = z[:, :, :, h - k : h - k + cols], z[:, :, :, h + k : h + k + cols]
        hs.add_(left).add_(right)
        hq.add_(zz[:, :, :, h - k : h - k + cols]).add_(zz[:, :, :, h + k : h + k + cols])
        hx.add_(right, alpha=k).sub_(left, alpha=k)
    # column pass: S, Q, S_x, and S_y from the row sums
    s = hs[:, :, h : h + rows].clone()
    q = hq[:, :, h : h + rows].clone()
    sx = hx[:, :, h : h + rows].clone()
    sy = torch.zeros_like(s)
    for k in range(1, h + 1):
        up, down = hs[:, :, h - k : h - k + rows], hs[:, :, h + k : h + k + rows]
        s.add_(up).add_(down)
        q.add_(hq[:, :, h - k : h - k + rows]).add_(hq[:, :, h + k : h + k + rows])
        sx.add_(hx[:, :, h - k : h - k + rows]).add_(hx[:, :, h + k : h + k + rows])
        sy.add_(down, alpha=k).sub_(up, alpha=k)
    count = float(size * size)
    moment = float(size * sum([k * k for k in range(-h, h + 1)]))
    m = s / count
    gx = sx / moment
    gy = sy / moment
    q.sub_(s * m).sub_(sx * gx).sub_(sy * gy).clamp_min_(0.0).div_(count - 3.0)
    dt = padded.dtype
    return m.to(dt), gx.to(dt), gy.to(dt), q.to(dt)


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
    rows, cols = v.shape[-2], v.shape[-1]
    sums = both[:, :, :, 0:cols].clone()  # separable window sums: 2 x (size - 1) adds
    for k in range(1, size):
        sums.add_(both[:, :, :, k : k + cols])
    box = sums[:, :, 0:rows].clone()
    for k in range(1, size):
        box.add_(sums[:, :, k : k + rows])
    local = torch.sqrt(box[:, 0:1] / box[:, 1:2].clamp_min(1.0))
    return torch.maximum(law, local)


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
