"""Diffuse interreflection within the visible scene: the relay operator of
:class:`~tof_fpn_torch.sim.multipath.Multipath`'s ``scene_relay`` part.

Geometry: a pinhole camera with horizontal field of view ``fov`` (deg) and square pixels
(focal length ``f_px = (W / 2) / tan(fov / 2)`` px); the ToF depth ``d_p`` is the radial distance
along pixel ``p``'s ray, so the scene point is ``P_p = d_p u_p`` (``u_p``: unit ray). Every
``step``-th pixel (both axes) stands for a source patch of area ``A_q = d_q^2 step^2 / f_px^2``
(m^2, obliquity ignored). A Lambertian patch whose radiance is what pixel ``q`` measures sends
``radiance A_q / (pi r^2)`` of irradiance to a point at distance ``r``; pixel ``p`` reads the
irradiance it receives times its own reflectance, with the same camera constant as its direct
light. So the samples of pixel ``p`` get, per sample ``n`` (first harmonic delayed by the extra
path ``r_pq + d_p - d_q`` over the direct path ``2 d_q`` of the light ``q`` measures)::

    relayed_p = rho_p sum_q A_q / (pi (r_pq^2 + L^2)) * samples_q (delayed)

``L`` (m, ``near_field``) keeps the sum finite where ``r -> 0``: neighbouring points of one surface
hardly light each other (their cosines vanish), which a model without surface normals can only
state as a near-field length. The cosines elsewhere are left out; the term's ``scene_relay``
(a relay efficiency, 1 = every pair facing each other) scales the whole sum.

With ``cosines=True`` the form factor is the Lambertian one with both obliquities,
``A_q cos(theta_q) cos(theta_p) / (pi (r^2 + L^2))``, the surface normals estimated from the
back-projected depth map (finite differences on the side of the smaller depth step, turned
towards the camera) and a pair that does not face each other (a cosine <= 0) relaying nothing:
points of one plane do not light each other, a floor lights the walls.
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict

import torch

__all__ = [
    "CACHE_BYTES",
    "MIRROR_MIN_SHARE",
    "back_project",
    "mirror_gains",
    "mirror_planes",
    "normals",
    "relay_matrix",
    "scene_relay",
]

#: a plane of the scene is a candidate mirror when at least this share of the pixels lie on it
MIRROR_MIN_SHARE: float = 0.08
_MIRRORS_MAX = 4  # planes kept, the largest first
_PLANE_COS = math.cos(math.radians(10.0))  # normals within 10 deg of the plane's
_PLANE_TOL_M = 0.03  # distance to the plane (m), plus 1 % of the depth

#: Relay matrices (one per frame size, geometry and step) kept in memory, the least recently used
#: dropped beyond this many bytes (the newest is always kept): the diagnosis profiles a few
#: geometries per candidate and a cache of two was recomputed in every round.
CACHE_BYTES: int = 1 << 30

_CACHE: OrderedDict = OrderedDict()
_LOCK = threading.Lock()  # the diagnosis fits candidates in threads
_BUILDING: dict = {}  # key -> Event, set when the thread building that matrix is done


def relay_matrix(
    depth: torch.Tensor,
    fov_deg: float,
    near_field: float,
    step: int,
    phase_per_metre: float,
    cosines: bool = False,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(W, W cos psi, W sin psi, source index (Q,))`` for one (H, W) depth map (m), each (Q, P):
    the form factors ``W = A_q / (pi (r^2 + L^2))`` (times both obliquities with ``cosines``)
    and ``psi`` the phase of the extra path. Cached for the last few (scene, settings);
    thread-safe: threads build different matrices at once, one waits for another building the
    same."""
    d64 = depth.detach().to(torch.float64)
    ramp = torch.arange(d64.numel(), dtype=torch.float64).view(d64.shape)
    # the scene by content (a freed tensor's address may come back with other values)
    content = (float(d64.sum()), float((d64 * ramp).sum()), float((d64 * d64).sum()))
    key = (tuple(depth.shape), content, fov_deg, near_field, step, phase_per_metre, cosines)
    with _LOCK:
        if key in _CACHE:
            _CACHE.move_to_end(key)
            return _CACHE[key]
        building = _BUILDING.get(key)
        if building is None:
            _BUILDING[key] = threading.Event()
    if building is not None:  # another thread builds it
        building.wait()
        with _LOCK:
            if key in _CACHE:
                return _CACHE[key]
        return relay_matrix(depth, fov_deg, near_field, step, phase_per_metre, cosines)
    try:
        out = _relay_matrix(d64, fov_deg, near_field, step, phase_per_metre, cosines)
        with _LOCK:
            _CACHE[key] = out
            while len(_CACHE) > 1 and sum(_nbytes(v) for v in _CACHE.values()) > CACHE_BYTES:
                _CACHE.popitem(last=False)
    finally:
        with _LOCK:
            _BUILDING.pop(key).set()
    return out


def _nbytes(entry) -> int:
    return sum(t.numel() * t.element_size() for t in entry)


def normals(points: torch.Tensor, depth: torch.Tensor) -> torch.Tensor:
    """Unit surface normals (H, W, 3) of back-projected ``points`` (H, W, 3), facing the camera:
    along each axis the one-sided difference with the smaller depth step (not across an edge)."""

    def tangent(axis: int) -> torch.Tensor:
        fwd = torch.roll(points, -1, axis) - points
        bwd = points - torch.roll(points, 1, axis)
        dfwd = (torch.roll(depth, -1, axis) - depth).abs()
        dbwd = (depth - torch.roll(depth, 1, axis)).abs()
        n = depth.shape[axis]
        last = torch.arange(n) == n - 1
        first = torch.arange(n) == 0
        shape = (-1, 1) if axis == 0 else (1, -1)
        dfwd = torch.where(last.view(shape), torch.inf, dfwd)
        dbwd = torch.where(first.view(shape), torch.inf, dbwd)
        return torch.where((dfwd <= dbwd).unsqueeze(-1), fwd, bwd)

    n = torch.linalg.cross(tangent(1), tangent(0))
    n = n / n.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    return torch.where(((n * points).sum(-1) > 0).unsqueeze(-1), -n, n)


def back_project(depth: torch.Tensor, fov_deg: float) -> torch.Tensor:
    """Scene points (H, W, 3) (m, camera at the origin, z forward) of a radial ``depth`` map
    (H, W) through a pinhole of horizontal field of view ``fov_deg`` and square pixels."""
    h, w = depth.shape
    f_px = (w / 2.0) / math.tan(math.radians(fov_deg) / 2.0)
    dt = depth.dtype if depth.dtype.is_floating_point else torch.float64
    yy = (torch.arange(h, dtype=dt).view(h, 1) - (h - 1) / 2.0).expand(h, w)
    xx = (torch.arange(w, dtype=dt).view(1, w) - (w - 1) / 2.0).expand(h, w)
    ray = torch.stack([xx / f_px, yy / f_px, torch.ones_like(xx)], -1)
    return depth.unsqueeze(-1) * ray / ray.norm(dim=-1, keepdim=True)


def mirror_planes(depth: torch.Tensor, fov_deg: float) -> torch.Tensor:
    """The large planes of a depth map (H, W) (m) as rows ``(nx, ny, nz, c)`` (M, 4), float64,
    ``n . X = c`` with ``c > 0`` (the camera on the side ``n . X < c``), the largest first, at
    most four, each holding at least ``MIRROR_MIN_SHARE`` of the valid pixels: a vote of every
    pixel's plane (its normal and offset, :func:`normals`) among the pixels of a coarse grid,
    the winner refitted by least squares (the smallest singular vector of its pixels), its
    pixels removed, again. The candidates of a specular second path (:func:`mirror_gains`)."""
    d = depth.detach().to(torch.float64)
    pts = back_project(d, fov_deg)
    nrm = normals(pts, d)
    step = max(1, int(math.sqrt(d.numel() / 4000)))
    p, n = pts[::step, ::step].reshape(-1, 3), nrm[::step, ::step].reshape(-1, 3)
    left = torch.isfinite(p).all(1) & (p[:, 2] > 0) & torch.isfinite(n).all(1)
    need = MIRROR_MIN_SHARE * float(left.sum())
    cand = torch.nonzero(left).view(-1)[:: max(1, int(left.sum()) // 400)]
    out = []
    for _ in range(_MIRRORS_MAX):
        if cand.numel() == 0 or float(left.sum()) < need:
            break
        nc, cc = n[cand], (n[cand] * p[cand]).sum(1)
        on = ((n @ nc.T) > _PLANE_COS) & (
            ((p @ nc.T) - cc.view(1, -1)).abs() < _PLANE_TOL_M + 0.01 * p.norm(dim=1, keepdim=True)
        )
        on &= left.view(-1, 1)
        best = int(on.sum(0).argmax())
        pix = on[:, best]
        if float(pix.sum()) < need:
            break
        q = p[pix]
        centre = q.mean(0)
        normal = torch.linalg.svd(q - centre, full_matrices=False)[2][-1]
        c = float(normal @ centre)
        if c < 0:
            normal, c = -normal, -c
        out.append(torch.cat([normal, normal.new_tensor([c])]))
        left &= ~pix
        cand = cand[left[cand]]
    return torch.stack(out) if out else d.new_zeros(0, 4)


def mirror_gains(
    depth: torch.Tensor, fov_deg: float, planes: torch.Tensor, phase_per_metre: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """``(gain, psi)``, each (M, H, W), of a specular second path off each plane of ``planes``
    (M, 4) (rows ``(n, c)``, :func:`mirror_planes`): a mirror in the plane ``n . X = c`` shows
    the emitter at ``C' = 2 c n``, so point ``P`` (depth ``d``) is lit once more from
    ``|P - C'| = L`` and returns the light both ways over the path ``d + L``: relative to its
    direct light, ``gain = (d / L)^2`` (inverse square from the image emitter, per unit
    reflectance of the mirror) and phase ``psi = phase_per_metre (L - d) / 2`` (0 for points on
    or behind the plane)."""
    d = depth.detach().to(torch.float64)
    pts = back_project(d, fov_deg)
    nv, c = planes[:, :3].to(torch.float64), planes[:, 3].to(torch.float64)
    side = c.view(-1, 1, 1) - torch.einsum("hwk,mk->mhw", pts, nv)  # > 0: the camera's side
    ell = (pts.unsqueeze(0) - 2.0 * (c.view(-1, 1) * nv).view(-1, 1, 1, 3)).norm(dim=-1)
    lit = (side > _PLANE_TOL_M + 0.01 * d) & torch.isfinite(ell) & (d > 0)
    gain = torch.where(lit, (d / ell.clamp_min(1e-9)) ** 2, torch.zeros_like(ell))
    psi = torch.where(lit, 0.5 * phase_per_metre * (ell - d), torch.zeros_like(ell))
    return gain, psi


def _relay_matrix(d64, fov_deg, near_field, step, phase_per_metre, cosines=False):
    h, w = d64.shape
    d = d64
    f_px = (w / 2.0) / math.tan(math.radians(fov_deg) / 2.0)
    pts3 = back_project(d, fov_deg)
    pts = pts3.reshape(-1, 3)
    sy = torch.arange(step // 2, h, step)
    sx = torch.arange(step // 2, w, step)
    src = (sy.view(-1, 1) * w + sx.view(1, -1)).reshape(-1)
    dp, dq = d.reshape(-1), d.reshape(-1)[src]
    area = dq * dq * (step / f_px) ** 2
    # (Q, P): the products take the sources' phasors from the left (no transposed copies)
    # (in place where a (Q, P) temporary is not needed again: the passes over the matrices are
    # most of the time)
    r = torch.cdist(pts[src], pts)
    r2 = r * r
    wgt = (r2 + near_field**2).mul_(math.pi).reciprocal_().mul_(area.view(-1, 1))
    if cosines:  # n_p . (Q - P) and n_q . (P - Q), as (Q, P) products (no (Q, P, 3) tensor)
        nrm = normals(pts3, d).reshape(-1, 3)
        nq = nrm[src]
        cos_p = (pts[src] @ nrm.T).sub_((nrm * pts).sum(1).view(1, -1)).clamp_min_(0)
        wgt.mul_(cos_p)
        del cos_p
        cos_q = (nq @ pts.T).sub_((nq * pts[src]).sum(1, keepdim=True)).clamp_min_(0)
        wgt.mul_(cos_q).div_(r2.clamp_min_(1e-18))
        del cos_q
    del r2
    psi = r.add_(dp.view(1, -1)).sub_(dq.view(-1, 1)).mul_(0.5 * phase_per_metre)
    wc = torch.cos(psi).mul_(wgt).float()
    ws = psi.sin_().mul_(wgt).float()
    return wgt.float(), wc, ws, src


def scene_relay(
    samples: torch.Tensor,
    depth: torch.Tensor,
    reflectance: torch.Tensor,
    fov_deg: float,
    near_field: float,
    step: int,
    phase_per_metre: float,
    cosines: bool = False,
) -> torch.Tensor:
    """The relayed samples (B, N, H, W) for samples (B, N, H, W) of one scene (depth and
    reflectance (H, W)), at unit efficiency; linear in ``samples`` (the graph is kept)."""
    b, n, h, w = samples.shape
    wgt, wc, ws, src = relay_matrix(depth, fov_deg, near_field, step, phase_per_metre, cosines)
    dt = samples.dtype
    wgt, wc, ws = wgt.to(dt), wc.to(dt), ws.to(dt)
    th = torch.arange(n, dtype=torch.float64) * (2 * math.pi / n)
    c, s = torch.cos(th).to(dt), torch.sin(th).to(dt)
    c = torch.where(c.abs() < 1e-12, torch.zeros_like(c), c)
    s = torch.where(s.abs() < 1e-12, torch.zeros_like(s), s)
    x = samples.reshape(b, n, h * w)[:, :, src]  # (B, N, Q)
    dc = x.mean(1)  # (B, Q)
    xr = (x * c.view(1, n, 1)).sum(1)
    xi = -(x * s.view(1, n, 1)).sum(1)
    # sum_q W_pq X_q e^{j psi_pq}, sum_q W_pq DC_q
    yr = xr @ wc - xi @ ws  # (B, P)
    yi = xr @ ws + xi @ wc
    ydc = dc @ wgt
    rho = reflectance.to(dt).reshape(1, h * w)
    yr, yi, ydc = yr * rho, yi * rho, ydc * rho
    out = ydc.unsqueeze(1) + (2.0 / n) * (
        yr.unsqueeze(1) * c.view(1, n, 1) - yi.unsqueeze(1) * s.view(1, n, 1)
    )
    return out.reshape(b, n, h, w)
