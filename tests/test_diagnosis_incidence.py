"""The baseline's angle of incidence: a scene given as albedo, lit by the camera's own source.

A matte surface returns the camera's light in proportion to ``cos(theta_inc) / d^2``; a scene whose
reflectance is the albedo (a ray-cast room, the ToF literature's camera) leaves a floor seen at a
grazing angle far darker than ``rho / d^2``. The recording here is written from that physics in
NumPy (not with the package's simulator): a pinhole camera, a room of planes, four correlation
samples with Poisson electrons, a black level, read noise and an ADC. Nothing else is planted, so
the diagnosis must name nothing (without the angle, the misfit was named ``pixel_gain``).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from tof_fpn_torch.diagnosis import diagnose
from tof_fpn_torch.diagnosis.incidence import (
    FOV_KEY,
    INCIDENCE_KEY,
    choose_incidence,
    incidence_cosine,
    incidence_spread,
)
from tof_fpn_torch.io import Recording, SceneData

H, W, T = 40, 56, 10
FOV_DEG = 70.0
F_MOD = 20e6
C0 = 299_792_458.0


def _room(h: int, w: int, fov_deg: float):
    """Radial depth (m), albedo and ``cos theta_inc`` (H, W) of a room seen through a pinhole: a
    floor 1.1 m below the camera (checker tiles), a back wall 4.5 m away (two shades), a side
    wall 1.5 m to the right; the camera pitched 10 degrees down (rows from the top)."""
    f = (w / 2) / math.tan(math.radians(fov_deg) / 2)
    u = np.arange(w) + 0.5 - w / 2
    v = np.arange(h) + 0.5 - h / 2
    uu, vv = np.meshgrid(u, v)
    d = np.stack([uu / f, -vv / f, np.ones_like(uu)], -1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    a = math.radians(10.0)
    rot = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    d = d @ rot.T
    planes = [  # (point, normal)
        (np.array([0.0, -1.1, 0.0]), np.array([0.0, 1.0, 0.0])),
        (np.array([0.0, 0.0, 4.5]), np.array([0.0, 0.0, -1.0])),
        (np.array([1.5, 0.0, 0.0]), np.array([-1.0, 0.0, 0.0])),
    ]
    best = np.full((h, w), np.inf)
    normal = np.zeros((h, w, 3))
    which = np.zeros((h, w), int)
    for i, (p, n) in enumerate(planes):
        dn = d @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (p @ n) / dn
        t = np.where((t > 1e-6) & np.isfinite(t), t, np.inf)
        closer = t < best
        best = np.where(closer, t, best)
        normal[closer] = n
        which[closer] = i
    pts = d * best[..., None]
    tiles = (np.floor(pts[..., 0] / 0.5) + np.floor(pts[..., 2] / 0.5)) % 2
    rho = np.select(
        [which == 0, which == 1, which == 2],
        [np.where(tiles == 0, 0.25, 0.6), np.where(pts[..., 0] < 0.3, 0.8, 0.45), 0.55],
    )
    cos_inc = np.clip(np.abs((normal * d).sum(-1)), 0.05, 1.0)
    return best, rho, cos_inc


def _albedo_recording(seed: int = 3):
    """The room of :func:`_room` recorded by an AMCW camera: Lambertian returns ``K rho cos /
    r^2`` (exposure: the brightest sample at 60 % of a 110 ke- well), ambient ``~ rho``, dark
    charge, Poisson electrons, 0.5 DN/e-, black level 256 DN, read noise 3 DN, rounded to DN;
    depth and amplitude by the first DFT bin. Returns ``(Recording, SceneData, cos_inc)``."""
    rng = np.random.default_rng(seed)
    r, rho, cos_inc = _room(H, W, FOV_DEG)
    theta = np.arange(4) * (math.pi / 2)
    phi = 4 * math.pi * F_MOD * r / C0
    unit = rho * cos_inc / r**2
    k = (0.6 * 110_000.0 - 50.0) / np.max(unit * 1.75 + 0.02 * rho)
    e_act, e_amb = k * unit, 0.02 * k * rho
    mu = e_amb + 50.0 + e_act * (1 + 0.75 * np.cos(phi - theta[:, None, None]))
    e = rng.poisson(np.broadcast_to(mu, (T, 4, H, W))).astype(np.float64)
    raw = np.round(0.5 * e + 256.0 + rng.normal(0.0, 3.0, e.shape)).clip(0, 65535)
    z = np.tensordot(np.exp(1j * theta), raw, axes=([0], [1]))
    amp = np.abs(z) / 2
    depth = np.mod(np.angle(z), 2 * math.pi) * C0 / (4 * math.pi * F_MOD)
    depth = np.where(amp >= 3.0, depth, np.nan)
    meta = {
        "modulation_frequency_hz": F_MOD,
        "integration_time_us": 1000.0,
        "n_phases": 4,
        "amplitude_unit": "DN",
    }
    rec = Recording(
        torch.from_numpy(depth[:, None].astype(np.float32)),
        torch.from_numpy(amp[:, None].astype(np.float32)),
        meta,
        torch.from_numpy(raw.astype(np.float32)),
    )
    scene = SceneData(torch.from_numpy(r), torch.from_numpy(rho), meta={"source": "test"})
    return rec, scene, cos_inc


def test_incidence_cosine_of_a_depth_map_is_the_surfaces():
    """The cosines from the depth map alone (normals by one-sided differences) are those of the
    surfaces the rays hit, at the camera's field of view; another field of view errs."""
    r, _, cos_inc = _room(H, W, FOV_DEG)
    c = incidence_cosine(torch.from_numpy(r), FOV_DEG).numpy()
    assert np.median(np.abs(np.log(c / cos_inc))) < 1e-3
    assert np.percentile(np.abs(np.log(c / cos_inc)), 95) < 0.02
    wrong = incidence_cosine(torch.from_numpy(r), 45.0).numpy()
    assert np.median(np.abs(np.log(wrong / cos_inc))) > 0.05


def test_the_spread_covers_the_pixels_whose_surface_is_open():
    """Where the depth map leaves a pixel's surface open (the corners of the room), the spread of
    the candidate normals' log cosines covers the error of the chosen one; inside the planes it
    is 0."""
    r, _, cos_inc = _room(H, W, FOV_DEG)
    depth = torch.from_numpy(r)
    err = np.abs(np.log(incidence_cosine(depth, FOV_DEG).numpy() / cos_inc))
    spread = incidence_spread(depth, FOV_DEG).numpy()
    bad = err > 0.02
    assert bad.sum() >= 3  # the room's corners
    assert (spread[bad] >= err[bad] - 1e-9).all()
    assert np.median(spread) < 1e-9
    assert (spread > 0.02).mean() < 0.1


def test_a_pixel_between_two_edges_is_open():
    """A post one pixel wide in front of a wall: along the row neither difference of its pixels
    lies on their surface, so their light is open (any angle) and they leave the likelihood; the
    wall's pixels beside it, whose other side lies on the wall, are not."""
    from tof_fpn_torch.diagnosis.incidence import FOV_KEY as FOV
    from tof_fpn_torch.diagnosis.incidence import incidence_open
    from tof_fpn_torch.sim import Scene

    r, _, _ = _room(H, W, FOV_DEG)
    post = r.copy()
    post[:, 20] = 1.5
    scene = Scene(torch.from_numpy(post)[None, None], torch.full((1, 1, H, W), 0.5))
    v = {INCIDENCE_KEY: 1.0, FOV: FOV_DEG}
    is_open = incidence_open(scene, v).numpy()
    assert is_open[:, 20].all()
    assert not is_open[:, 19].any() and not is_open[:, 21].any()
    assert is_open.mean() < 0.1
    assert incidence_open(scene, {INCIDENCE_KEY: 0.0, FOV: FOV_DEG}) is None


def test_the_depth_noise_of_an_open_pixel_follows_its_own_light():
    """Inside a plane the model's light stands (1); at a corner pixel, whose face the depth map
    leaves open, the observed amplitude over the model's, within the spread of its candidate
    angles."""
    from types import SimpleNamespace

    from tof_fpn_torch.diagnosis.incidence import FOV_KEY as FOV
    from tof_fpn_torch.diagnosis.incidence import open_light
    from tof_fpn_torch.sim import Scene

    r, _, _ = _room(H, W, FOV_DEG)
    depth = torch.from_numpy(r)
    scene = Scene(depth[None, None], torch.full((1, 1, H, W), 0.5))
    spread = incidence_spread(depth, FOV_DEG)
    mu_a = torch.full((H, W), 100.0, dtype=torch.float64)
    obs = SimpleNamespace(m_a=torch.full((H, W), 40.0, dtype=torch.float64), n=torch.ones(H, W))
    light = open_light(scene, {INCIDENCE_KEY: 1.0, FOV: FOV_DEG}, obs, mu_a)
    plain = spread < 1e-9
    assert plain.float().mean() > 0.8
    assert torch.allclose(light[plain], torch.ones_like(light[plain]))
    wide = spread > -math.log(0.4)
    assert wide.any()
    assert torch.allclose(light[wide], torch.full_like(light[wide], 0.4))
    some = (spread > 0.01) & (spread < 0.5)
    assert torch.allclose(light[some], torch.exp(-spread[some]))
    assert open_light(scene, {INCIDENCE_KEY: 0.0, FOV: FOV_DEG}, obs, mu_a) is None


def test_the_choice_finds_the_angle_and_the_field_of_view():
    """The amplitude of the albedo scene against ``rho / d^2`` points at Lambert's law at about
    the camera's field of view; against ``rho cos / d^2`` (a reflectance that holds the angle)
    it does not."""
    from tof_fpn_torch.diagnosis.data import observe

    rec, scene, cos_inc = _albedo_recording()
    obs = observe(rec, scene)
    a0 = obs.reflectance / obs.scene_depth**2
    ok = obs.known & (obs.n > 0)
    got = choose_incidence(obs, a0, ok)
    assert got[INCIDENCE_KEY] == 1.0
    assert abs(got[FOV_KEY] - FOV_DEG) <= 4.0
    held = choose_incidence(obs, a0 * torch.from_numpy(cos_inc), ok)
    assert held[INCIDENCE_KEY] == 0.0


@pytest.mark.slow
def test_a_plain_albedo_recording_is_named_none():
    """Nothing planted in a scene given as albedo: the diagnosis names nothing, and its
    baseline holds the angle of incidence (a power near 1 at about the camera's field of
    view)."""
    rec, scene, _ = _albedo_recording()
    d = diagnose(rec, scene, seed=0)
    assert d.effects == [], d.report["effects"]
    assert d.baseline.values[INCIDENCE_KEY] == 1.0
    assert abs(d.baseline.values[FOV_KEY] - FOV_DEG) <= 4.0


def test_a_reflectance_that_holds_the_angle_keeps_the_baseline_without_it():
    """The package's simulator states a reflectance that holds the angle (``k rho / d^2``): the
    baseline keeps ``rho / d^2``."""
    from test_diagnosis import _recording

    from tof_fpn_torch.diagnosis.run import _baseline, observe

    rec, scene = _recording(None, seed=4, frames=6)
    obs = observe(rec, scene)
    assert _baseline(obs, None).values[INCIDENCE_KEY] == 0.0
