"""Optical terms of the simulator: the noisy-clip moments of ``Saturation``, the relay within
the scene of ``Multipath``."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from tof_fpn_torch import constants as K
from tof_fpn_torch.sim import Camera, Multipath, Photons, Saturation, SimState, synthetic_scene
from tof_fpn_torch.sim.relay import scene_relay


def test_saturation_noisy_moments_match_monte_carlo():
    """Mean and variance of a hard clip of Gaussian samples (none, partly and fully clipped) as
    sampled; a fully clipped sample reads the level with no variance, an unclipped one is left
    alone."""
    level = 100.0
    mean = torch.tensor([0.0, 90.0, 100.0, 110.0, 200.0, 1e5], dtype=torch.float64)
    var = torch.tensor([100.0, 100.0, 400.0, 100.0, 100.0, 1e5], dtype=torch.float64)
    m, v = Saturation(level).noisy_moments(mean, var)
    gen = torch.Generator().manual_seed(0)
    x = mean[:, None] + var.sqrt()[:, None] * torch.randn(
        6, 400_000, generator=gen, dtype=torch.float64
    )
    c = x.clamp(max=level)
    assert torch.allclose(m, c.mean(1), atol=0.05)
    assert torch.allclose(v, c.var(1), rtol=0.02, atol=1e-6)
    assert m[0] == mean[0] and abs(float(v[0]) - 100.0) < 1e-6
    assert float(m[-1]) == level and float(v[-1]) == 0.0


def test_saturation_noisy_moments_have_finite_gradients():
    lv = torch.tensor(100.0, dtype=torch.float64, requires_grad=True)
    mean = torch.tensor([0.0, 100.0, 1e6], dtype=torch.float64, requires_grad=True)
    m, v = Saturation(lv).noisy_moments(mean, torch.full_like(mean, 100.0))
    (m.sum() + v.sum()).backward()
    assert torch.isfinite(lv.grad) and torch.isfinite(mean.grad).all()
    assert float(lv.grad) > 0


def _relay_by_loops(samples, depth, rho, fov, near, step, ppm):
    """The scene relay written pair by pair (complex phasors): docs of sim.relay."""
    n, h, w = samples.shape
    f_px = (w / 2) / math.tan(math.radians(fov) / 2)
    th = [2 * math.pi * k / n for k in range(n)]

    def point(y, x):
        ray = ((x - (w - 1) / 2) / f_px, (y - (h - 1) / 2) / f_px, 1.0)
        norm = math.sqrt(sum(c * c for c in ray))
        return [depth[y, x] * c / norm for c in ray]

    out = torch.zeros_like(samples)
    for py in range(h):
        for px in range(w):
            pp, z, dc = point(py, px), 0j, 0.0
            for qy in range(step // 2, h, step):
                for qx in range(step // 2, w, step):
                    pq, dq = point(qy, qx), float(depth[qy, qx])
                    r = math.dist(pp, pq)
                    wt = dq * dq * (step / f_px) ** 2 / (math.pi * (r * r + near * near))
                    s = [float(samples[k, qy, qx]) for k in range(n)]
                    x1 = sum(s[k] * complex(math.cos(th[k]), -math.sin(th[k])) for k in range(n))
                    psi = 0.5 * ppm * (r + float(depth[py, px]) - dq)
                    z += wt * x1 * complex(math.cos(psi), math.sin(psi))
                    dc += wt * sum(s) / n
            for k in range(n):
                val = dc + (2 / n) * (z.real * math.cos(th[k]) - z.imag * math.sin(th[k]))
                out[k, py, px] = float(rho[py, px]) * val
    return out


def test_scene_relay_matches_the_pairwise_sum():
    """The relay within the scene (matrix form, cached) equals the pair-by-pair sum of
    Lambertian patches over their own extra paths."""
    gen = torch.Generator().manual_seed(3)
    h, w, n = 6, 8, 4
    depth = 1.0 + 3.0 * torch.rand(h, w, generator=gen, dtype=torch.float64)
    rho = 0.2 + 0.6 * torch.rand(h, w, generator=gen, dtype=torch.float64)
    samples = 100 + 50 * torch.rand(1, n, h, w, generator=gen, dtype=torch.float64)
    got = scene_relay(samples, depth, rho, 60.0, 0.5, 2, 0.84)
    want = _relay_by_loops(samples[0], depth, rho, 60.0, 0.5, 2, 0.84)
    assert torch.allclose(got[0], want, rtol=1e-4, atol=1e-4)


def test_multipath_scene_relay_is_linear_and_off_by_default():
    """``Multipath(scene_relay=b)`` adds ``b`` times the relay to the samples; with the defaults
    the samples are unchanged."""
    cam = Camera()
    scene = synthetic_scene(24, 32, seed=1, depth_range=(0.6, 4.0))
    act = Photons().mean_samples(cam, scene).double()

    def run(term):
        return term.apply(SimState(cam, scene, act.clone(), None)).samples

    assert torch.equal(run(Multipath()), act)
    one, two = run(Multipath(scene_relay=0.01)) - act, run(Multipath(scene_relay=0.02)) - act
    assert float(one.abs().max()) > 0
    assert torch.allclose(two, 2 * one, rtol=1e-9, atol=1e-9)
    with pytest.raises(ValueError, match="field_of_view"):
        Multipath(field_of_view=180.0)


def test_scene_relay_uses_at_most_the_maximum_number_of_sources():
    """``relay_step`` is a minimum: a large image is relayed from at most
    ``MULTIPATH_MAX_SOURCES`` source patches (memory and time stay bounded)."""
    from tof_fpn_torch import constants as K
    from tof_fpn_torch.sim import relay

    cam = Camera()
    scene = synthetic_scene(40, 60, seed=2, depth_range=(0.6, 4.0))
    act = Photons().mean_samples(cam, scene).double()
    relay._CACHE.clear()
    Multipath(scene_relay=0.01, relay_step=1).apply(SimState(cam, scene, act, None))
    ((wgt, *_),) = relay._CACHE.values()
    assert 0.5 * K.MULTIPATH_MAX_SOURCES < wgt.shape[0] <= K.MULTIPATH_MAX_SOURCES
    assert wgt.shape[1] == 40 * 60


def _two_planes(h, w, fov, split=None):
    """Depth (H, W) of two planes seen through the pinhole (left: a wall facing the camera at a
    slant, right: a farther plane), and their unit normals (H, W, 3) facing the camera."""
    f_px = (w / 2) / math.tan(math.radians(fov) / 2)
    yy = (torch.arange(h, dtype=torch.float64).view(h, 1) - (h - 1) / 2).expand(h, w) / f_px
    xx = (torch.arange(w, dtype=torch.float64).view(1, w) - (w - 1) / 2).expand(h, w) / f_px
    u = torch.stack([xx, yy, torch.ones_like(xx)], -1)
    u = u / u.norm(dim=-1, keepdim=True)
    na = torch.tensor([0.3, -0.2, -1.0], dtype=torch.float64)
    nb = torch.tensor([-0.5, 0.1, -1.0], dtype=torch.float64)
    na, nb = na / na.norm(), nb / nb.norm()
    left = (torch.arange(w) < (w // 2 if split is None else split)).view(1, w, 1).expand(h, w, 1)
    n = torch.where(left, na, nb)
    c = torch.where(left[..., 0], -2.0 * float(na[2]), -3.5 * float(nb[2]))  # n . P = c
    depth = c / (u * n).sum(-1)  # the ray hits n . (d u) = c
    return depth, -n  # normals towards the camera (n . P > 0: turn them)


def test_cosine_relay_matches_the_pairwise_sum_with_normals():
    """With ``cosines`` the relay weighs every pair by both obliquities, the normals estimated
    from the depth map: equal to the pair-by-pair sum with the planes' true normals, and a single
    plane does not light itself."""
    from tof_fpn_torch.sim.relay import normals, relay_matrix

    h, w, n, fov, near, step, ppm = 6, 8, 4, 60.0, 0.3, 2, 0.84
    depth, nrm = _two_planes(h, w, fov)
    f_px = (w / 2) / math.tan(math.radians(fov) / 2)
    yy = (torch.arange(h, dtype=torch.float64).view(h, 1) - (h - 1) / 2).expand(h, w) / f_px
    xx = (torch.arange(w, dtype=torch.float64).view(1, w) - (w - 1) / 2).expand(h, w) / f_px
    ray = torch.stack([xx, yy, torch.ones_like(xx)], -1)
    pts = depth.unsqueeze(-1) * ray / ray.norm(dim=-1, keepdim=True)
    assert torch.allclose(normals(pts, depth), nrm, atol=1e-9)
    gen = torch.Generator().manual_seed(4)
    rho = 0.2 + 0.6 * torch.rand(h, w, generator=gen, dtype=torch.float64)
    samples = 100 + 50 * torch.rand(1, n, h, w, generator=gen, dtype=torch.float64)
    got = scene_relay(samples, depth, rho, fov, near, step, ppm, cosines=True)
    # the pairwise sum with the true obliquities: the plain relay of each pair times its cosines
    wgt, *_, src = relay_matrix(depth, fov, near, step, ppm)
    p, q = pts.reshape(-1, 3), pts.reshape(-1, 3)[src]
    d = q.unsqueeze(0) - p.unsqueeze(1)
    r = d.norm(dim=-1).clamp_min(1e-12)
    cos_p = ((d / r.unsqueeze(-1)) * nrm.reshape(-1, 1, 3)).sum(-1).clamp_min(0)
    cos_q = (-(d / r.unsqueeze(-1)) * nrm.reshape(-1, 3)[src].unsqueeze(0)).sum(-1).clamp_min(0)
    want = torch.zeros_like(samples)
    for i, qi in enumerate(src.tolist()):
        one = torch.zeros(1, 1, h, w, dtype=torch.float64)
        one.view(-1)[qi] = 1.0
        part = scene_relay(samples * one, depth, rho, fov, near, step, ppm)
        want = want + part * (cos_p[:, i] * cos_q[:, i]).view(1, 1, h, w)
    assert torch.allclose(got, want, rtol=1e-4, atol=1e-4)
    assert float(got.abs().max()) > 0
    flat, _ = _two_planes(h, w, fov, split=w)  # one plane: every pair has a zero cosine
    alone = scene_relay(samples, flat, rho, fov, near, 1, ppm, cosines=True)
    plain = scene_relay(samples, flat, rho, fov, near, 1, ppm)
    assert float(alone.abs().max()) < 1e-6 * float(plain.abs().max())


def test_source_map_scales_the_light_each_point_relays():
    """``Multipath(source_map=m)`` relays ``m`` times each point's light: zero relays nothing,
    a constant c is c times the plain relay; a map of another size or with negative values is
    refused."""
    cam = Camera()
    scene = synthetic_scene(24, 32, seed=1, depth_range=(0.6, 4.0))
    act = Photons().mean_samples(cam, scene).double()

    def run(term):
        return term.apply(SimState(cam, scene, act.clone(), None)).samples - act

    plain = run(Multipath(scene_relay=0.01))
    assert torch.allclose(run(Multipath(scene_relay=0.01, source_map=torch.zeros(24, 32))), 0 * act)
    twice = run(Multipath(scene_relay=0.01, source_map=torch.full((24, 32), 2.0)))
    assert torch.allclose(twice, 2 * plain, rtol=1e-6, atol=1e-6)
    with pytest.raises(ValueError, match="source_map"):
        Multipath(scene_relay=0.01, source_map=torch.full((24, 32), -1.0))
    with pytest.raises(ValueError, match="frames are"):
        run(Multipath(scene_relay=0.01, source_map=torch.ones(10, 10)))


def test_relay_cache_is_bounded_in_bytes(monkeypatch):
    """The relay matrices are kept up to ``CACHE_BYTES`` (the least recently used dropped, the
    newest always kept): several geometries stay cached when they fit."""
    from tof_fpn_torch.sim import relay

    depth = 1.0 + torch.rand(12, 16, generator=torch.Generator().manual_seed(0))
    relay._CACHE.clear()
    for fov in (50.0, 70.0, 90.0):
        relay.relay_matrix(depth, fov, 0.3, 2, 0.84)
    assert len(relay._CACHE) == 3
    one = relay._nbytes(next(iter(relay._CACHE.values())))
    monkeypatch.setattr(relay, "CACHE_BYTES", int(1.5 * one))
    relay.relay_matrix(depth, 60.0, 0.3, 2, 0.84)
    assert len(relay._CACHE) == 1 and next(iter(relay._CACHE))[2] == 60.0
    relay._CACHE.clear()


def test_relay_matrices_built_by_threads_at_once(monkeypatch):
    """Threads build different geometries at once (not one after another under one lock) and
    one that asks for a matrix another is building waits for it: each built once, every thread
    gets the same tensors, the same as a build alone."""
    import threading
    import time
    from concurrent.futures import ThreadPoolExecutor

    from tof_fpn_torch.sim import relay

    depth = 1.0 + torch.rand(12, 16, generator=torch.Generator().manual_seed(1))
    relay._CACHE.clear()
    builds, running, overlap = [], [0], [0]
    lock = threading.Lock()
    build = relay._relay_matrix

    def slow_build(*args):
        with lock:
            running[0] += 1
            overlap[0] = max(overlap[0], running[0])
        builds.append(args[1])
        time.sleep(0.2)  # long enough for the other threads to ask meanwhile
        out = build(*args)
        with lock:
            running[0] -= 1
        return out

    monkeypatch.setattr(relay, "_relay_matrix", slow_build)
    fovs = [50.0, 70.0] * 3
    with ThreadPoolExecutor(max_workers=6) as ex:
        got = list(ex.map(lambda f: relay.relay_matrix(depth, f, 0.3, 2, 0.84), fovs))
    assert sorted(builds) == [50.0, 70.0]  # each geometry built once
    assert overlap[0] == 2  # the two at the same time
    for f, out in zip(fovs, got, strict=True):
        assert out is got[fovs.index(f)]
        alone = build(depth.to(torch.float64), f, 0.3, 2, 0.84)
        assert all(torch.equal(a, b) for a, b in zip(out, alone, strict=True))
    assert not relay._BUILDING
    relay._CACHE.clear()


def _room(h: int, w: int, fov: float) -> torch.Tensor:
    """Radial depth (H, W) of a box room seen through a pinhole: a floor 1.2 m below the camera,
    a back wall at z = 4 m and a side wall at x = 1.5 m (whichever a ray meets first)."""
    from tof_fpn_torch.sim.relay import back_project

    rays = back_project(torch.ones(h, w, dtype=torch.float64), fov)
    hits = []
    for normal, c in (((0.0, 1.0, 0.0), 1.2), ((0.0, 0.0, 1.0), 4.0), ((1.0, 0.0, 0.0), 1.5)):
        t = c / (rays @ torch.tensor(normal, dtype=torch.float64))
        hits.append(torch.where(t > 0, t, torch.full_like(t, torch.inf)))
    return torch.stack(hits).amin(0)


def test_mirror_planes_are_the_rooms_planes():
    """The large planes of a box room's depth map are found with their normals and offsets (the
    floor, back wall and side wall, largest first); a sphere has none."""
    from tof_fpn_torch.sim.relay import back_project, mirror_planes

    fov = 70.0
    depth = _room(60, 80, fov)
    planes = mirror_planes(depth, fov)
    truth = {(0, 1, 0): 1.2, (0, 0, 1): 4.0, (1, 0, 0): 1.5}
    assert len(planes) == 3
    found = {}
    for row in planes:
        key = tuple(int(round(float(v))) for v in row[:3])
        assert float(row[:3].norm()) == pytest.approx(1.0, abs=1e-9)
        assert float(row[:3] @ torch.tensor(key, dtype=torch.float64)) > 0.999
        found[key] = float(row[3])
    assert found == pytest.approx(truth, abs=0.01)
    pts = back_project(depth, fov)
    on = [int(((pts @ p[:3] - p[3]).abs() < 0.01).sum()) for p in planes]
    assert on == sorted(on, reverse=True)  # the largest first
    rays = back_project(torch.ones(60, 80, dtype=torch.float64), fov)
    b = rays[..., 2] * 3.0  # a sphere of radius 1 m at 3 m: |t u - c|^2 = 1
    ball = b - torch.sqrt((b * b - 8.0).clamp_min(0))
    ball = torch.where(b * b > 8.0, ball, 6.0 / rays[..., 2])  # a far wall (z = 6 m) around it
    (wall,) = mirror_planes(ball, fov)  # the wall only
    assert float(wall[2]) > 0.999 and float(wall[3]) == pytest.approx(6.0, abs=0.01)


def test_mirror_gains_follow_fermats_path():
    """The specular path off a plane, against a direct minimisation (SciPy) of the path
    camera -> mirror point -> scene point over the mirror plane: the same length ``L`` (so the
    same extra phase) and the inverse-square gain ``(d / L)^2``; points below the floor get
    nothing."""
    from scipy.optimize import minimize

    from tof_fpn_torch.sim.relay import back_project, mirror_gains

    fov, ppm = 70.0, 0.84
    depth = _room(30, 40, fov)
    floor = torch.tensor([[0.0, 1.0, 0.0, 1.2]], dtype=torch.float64)
    gain, psi = mirror_gains(depth, fov, floor, ppm)
    pts = back_project(depth, fov)
    for y, x in ((3, 5), (10, 30), (14, 2), (6, 20)):
        p = pts[y, x].numpy()
        if p[1] > 1.2 - 0.05:
            continue

        def path(fxz, p=p):
            f = np.array([fxz[0], 1.2, fxz[1]])
            return np.linalg.norm(f) + np.linalg.norm(p - f)

        best = minimize(
            path,
            x0=[p[0] / 2, p[2] / 2],
            method="Nelder-Mead",
            options={"xatol": 1e-10, "fatol": 1e-12, "maxiter": 4000},
        )
        d = float(depth[y, x])
        ell = float(best.fun)
        assert float(psi[0, y, x]) == pytest.approx(0.5 * ppm * (ell - d), rel=1e-6)
        assert float(gain[0, y, x]) == pytest.approx((d / ell) ** 2, rel=1e-6)
    on, above = pts[..., 1] > 1.2 - 0.02, pts[..., 1] < 1.2 - 0.1  # on the floor, above it
    assert on.any() and float(gain[0][on].abs().max()) == 0.0
    assert float(gain[0][above].min()) > 0


def test_multipath_mirror_adds_the_delayed_phasor():
    """``Multipath(mirrors=...)``: every pixel's first harmonic becomes ``X (1 + w g e^{j psi})``
    and its offset ``DC (1 + w g)`` (``g, psi``: :func:`mirror_gains`); weight zero adds
    nothing; rows that are not (M, 5) or a negative weight are refused."""
    from tof_fpn_torch.sim.phasor import fundamental
    from tof_fpn_torch.sim.relay import mirror_gains

    cam = Camera()
    h, w, fov = 24, 32, 70.0
    depth = _room(h, w, fov).float().view(1, 1, h, w)
    scene = synthetic_scene(h, w, seed=1)
    scene = type(scene)(depth=depth, reflectance=scene.reflectance)
    act = Photons().mean_samples(cam, scene).double()
    row = torch.tensor([[0.0, 1.0, 0.0, 1.2, 0.3]], dtype=torch.float64)
    out = (
        Multipath(scene_relay=1.0, source_map=torch.zeros(h, w), mirrors=row)
        .apply(SimState(cam, scene, act.clone(), None))
        .samples
    )
    ppm = 4 * math.pi * cam.modulation_frequency / K.SPEED_OF_LIGHT_AIR
    g, psi = mirror_gains(depth[0, 0], fov, row[:, :4], ppm)
    xr, xi = fundamental(act)
    yr, yi = fundamental(out)
    z = torch.complex(xr, xi) * (1 + 0.3 * g * torch.exp(1j * psi))
    assert torch.allclose(torch.complex(yr, yi), z, rtol=1e-6, atol=1e-6)
    assert torch.allclose(out.mean(1), act.mean(1) * (1 + 0.3 * g), rtol=1e-6)
    assert float((g > 0).float().mean()) > 0.3
    none = row.clone()
    none[0, 4] = 0.0
    same = (
        Multipath(scene_relay=1.0, source_map=torch.zeros(h, w), mirrors=none)
        .apply(SimState(cam, scene, act.clone(), None))
        .samples
    )
    assert torch.equal(same, act)
    with pytest.raises(ValueError, match="mirrors"):
        Multipath(scene_relay=1.0, mirrors=row[:, :4])
    with pytest.raises(ValueError, match="mirrors"):
        Multipath(scene_relay=1.0, mirrors=-row)


def test_vignetting_gain_map_is_the_relative_illumination():
    """``Vignetting(gain_map=g)`` multiplies every sample by ``g``; a map of another size, with
    a zero or a negative value is refused."""
    from tof_fpn_torch.sim import Vignetting

    cam = Camera()
    scene = synthetic_scene(16, 20, seed=1)
    act = Photons().mean_samples(cam, scene).double()
    g = 0.5 + torch.rand(16, 20, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    out = Vignetting(gain_map=g).apply(SimState(cam, scene, act.clone(), None)).samples
    assert torch.allclose(out, act * g.view(1, 1, 16, 20))
    with pytest.raises(ValueError, match="frames are"):
        Vignetting(gain_map=torch.ones(5, 5)).apply(SimState(cam, scene, act.clone(), None))
    for bad in (torch.zeros(16, 20), -torch.ones(16, 20)):
        with pytest.raises(ValueError, match="gain_map"):
            Vignetting(gain_map=bad)
