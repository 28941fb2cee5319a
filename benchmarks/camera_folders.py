"""Folders of depth-camera files with known truth, written from the physics of the measurement.

Each folder is what one continuous-wave time-of-flight (ToF) camera writes: a uint16 depth PNG in
millimetres (0 = invalid) and a uint16 amplitude PNG in counts per frame, named
``<stem>_depth.png`` / ``<stem>_amplitude.png``. One camera has one fixed pattern, the same in
every frame of its folder. The frames show different scenes (different poses, different objects),
except in the ``still`` family, whose frames show one scene and differ only by their noise.

Nothing here comes from the package's cleaning code: the scenes are ray-cast, and the measurement
follows the ToF literature:

- Lange & Seitz, "Solid-state time-of-flight range camera", IEEE J. Quantum Electron. 37(3),
  2001: phase ``phi = 4 pi f d / c`` of the reflected modulated light, with shot-noise limited
  range error ``sigma_d ~ c / (4 pi f) * sqrt(A + B) / A`` (signal amplitude ``A``, background
  ``B``; ``~ 1 / A`` where the background dominates, the low-sensing case).
- Hansard, Lee, Choi & Horaud, "Time-of-Flight Cameras: Principles, Methods and Applications",
  Springer 2013: amplitude ``A ~ albedo cos(incidence) / d^2``; mixed ("flying") pixels, whose
  measurement is the phase of the *sum* of the complex returns that fall on one pixel.
- Frank, Plaue, Rapp, Koethe, Jaehne & Hamprecht, "Theoretical and experimental error analysis of
  continuous-wave time-of-flight range cameras", Opt. Eng. 48(1), 2009: depth noise from the
  noise of the correlation samples, Gaussian in depth at the signal levels used here.
- Foix, Alenya & Torras, "Lock-in time-of-flight (ToF) cameras: a survey", IEEE Sensors J.
  11(9), 2011: the error sources (noise, saturation, low-signal invalidation, mixed pixels,
  fixed-pattern noise).

The camera of a folder (drawn from the seed): modulation frequency 15 or 20 MHz (unambiguous
range 10 / 7.5 m; returns beyond 95 % of it are dropped), horizontal field of view 55-75 degrees,
one exposure for all frames, set so that the first frame's median amplitude is 40-220 counts
(80 % of cameras; the others 300-1200), background ``B`` 1-4 times that, depth noise
``sigma_d = k sqrt(A + B) / A`` with ``k`` giving 1.2-4.5 mm at that median (so 1-10 mm over
most pixels, more in the darkest), amplitude noise ``sigma_d / (c / (4 pi f)) * A`` (the same
phasor noise), amplitude PRNU 1 % (EMVA 1288). A pixel is invalid (depth 0) where its measured
amplitude is below ``a_min`` (12-25 counts), where it saturates (``A >= a_sat`` = 4095, amplitude
stored as ``a_sat``) or where its ray has no return. Mixed pixels: at depth edges each pixel is
sampled 3 x 3 times and measures the phase of the mean phasor; a pixel whose measured distance
moves more than 3 mm from its centre's is flagged ``flying`` (it stays valid, as in real cameras).
Depth is rounded to mm, amplitude to counts.

Fixed-pattern kinds (:data:`PATTERNS`), each zero-mean and scaled to a stated RMS (``pattern_rms``
in the truth):

- ``none``: no pattern.
- ``columns``: white column offsets, iid per column, 2-5 mm sd: the offset spread of
  column-parallel ADCs / column amplifiers (DSNU in the sense of EMVA Standard 1288, release 4.0,
  2021; column-wise offsets of CMOS image sensors with column-parallel read-out, e.g. Snoeij,
  Theuwissen, Makinwa & Huijsing, "A CMOS imager with column-level ADC using dynamic column
  fixed-pattern noise reduction", IEEE JSSC 41(12), 2006).
- ``stripes``: the periodic column stripes of the PMD CamCube at spatial frequencies ``2 pi / 3``
  and ``pi`` along the rows (Georgiev, Bregovic & Gotchev, "Fixed-pattern noise suppression in
  low-sensing environment of time-of-flight devices", IEEE SAS 2015): ``s(x) = a1 cos(2 pi x / 3
  + t1) + a2 cos(pi x)``, 1.5-4 mm RMS, the same in every row.
- ``rows``: iid row offsets (row-wise read-out), 1.5-4 mm sd.
- ``kinect_p0``: a real per-pixel map: the fine structure of one of the Kinect v2 factory
  phase-offset (P0) tables in ``tests/data/real/kinect_v2_p0/`` (the pi offsets between alternating
  rows removed, a 2-D polynomial of degree 4 subtracted, phase converted to metres at the plane's
  modulation frequency, cropped to the frame), 1.5-4 mm RMS.
- ``complex_offset``: read-out offsets that differ between the taps do not cancel in the
  four-phase demodulation and add a complex offset ``c`` (per pixel: a column part and a smaller
  pixel part) to the phasor of the signal: ``z = A e^{j phi} + c``, measured phase ``angle(z)``,
  so the depth error ``c_light / (4 pi f) * angle(1 + c e^{-j phi} / A)`` scales like ``1 / A``
  and depends on the scene's phase. Its stated RMS is the one at the reference amplitude
  ``A_ref`` = 100 counts averaged over phases, ``c_light / (4 pi f) * rms|c| / (sqrt(2) A_ref)``,
  2-5 mm.
- ``stripes_low_a``: the CamCube stripes as they arise, in the correlation samples: column
  read-out offsets ``s(x) cos(2 pi n / N - psi)`` of the N samples decode to the complex offset
  ``c(x) = s(x) e^{j psi}``, ``s`` with frequencies ``2 pi / 3`` and ``pi`` as in ``stripes``, so
  the stripes grow like ``1 / A`` in the dark parts of a scene (the low-sensing regime of Georgiev
  et al. 2015). RMS stated as for ``complex_offset``, 2-5 mm at ``A_ref``.

Truth (returned by :func:`make_folder`, saved as ``out_dir/truth.npz`` beside the folder
``out_dir/frames/`` that a cleaner reads):

- ``depth`` (T, H, W) true depth Z in metres of the pixel centre's ray (NaN where it hits nothing
  in range); ``amplitude`` (T, H, W) noise-free amplitude ``A`` in counts; ``sd`` (T, H, W) depth
  noise sd in metres; ``ray_norm`` (H, W) the length of each pixel's ray per metre of depth
  (radial distance = depth x ray_norm, phase ``phi = 4 pi f_mod depth ray_norm / c``);
- ``pattern`` (H, W) the fixed pattern in metres (for the complex kinds, :data:`COMPLEX_KINDS`:
  its effect on the radial distance at ``A_ref`` and phase 0); ``pattern_frames`` (T, H, W) the
  pattern's actual depth effect in each frame (equal to ``pattern`` in every frame for the
  additive kinds); ``offset`` (H, W) complex ``c`` in counts (zero for the additive kinds);
- ``observed`` (T, H, W) the measured depth in metres before the rounding to mm (NaN invalid),
  ``noise`` (T, H, W) its noise realisation, ``valid`` and ``flying`` (T, H, W) bool masks;
- scalars: ``pattern_rms``, ``f_mod``, ``a_ref``, ``a_min``, ``a_sat``, ``background``, strings
  ``family``, ``pattern_kind``, ``stems``, int ``seed``.

Outside flying pixels, ``observed = depth + pattern_frames + noise``.

``python benchmarks/camera_folders.py OUT --family F --pattern P --seed S`` writes one folder;
``python benchmarks/camera_folders.py --all OUT`` a grid (every family x every pattern, one dev
seed). Seeds >= :data:`HELD_OUT_START` are the held-out split (:func:`split`).
"""

from __future__ import annotations

import argparse
import zlib
from functools import lru_cache
from pathlib import Path

import numpy as np

C_LIGHT = 299_792_458.0
FAMILIES: tuple[str, ...] = (
    "slanted_planes",
    "boxes",
    "room_corner",
    "staircase",
    "textured",
    "cylinders",
    "still",
)
PATTERNS: tuple[str, ...] = (
    "none",
    "columns",
    "stripes",
    "rows",
    "kinect_p0",
    "complex_offset",
    "stripes_low_a",
)
#: the kinds that enter as a complex offset of the phasor (depth effect ~ 1 / A)
COMPLEX_KINDS: tuple[str, ...] = ("complex_offset", "stripes_low_a")
#: seeds at or above this are held out (run once, at the end)
HELD_OUT_START = 1000
#: frame sizes drawn when none is given (one odd)
SIZES: tuple[tuple[int, int], ...] = ((120, 160), (144, 176), (171, 229), (180, 240), (240, 320))
#: the amplitude at which ``complex_offset``'s RMS is stated, counts
A_REF = 100.0
#: stated RMS ranges, metres
RMS_RANGE = {
    "columns": (2e-3, 5e-3),
    "stripes": (1.5e-3, 4e-3),
    "rows": (1.5e-3, 4e-3),
    "kinect_p0": (1.5e-3, 4e-3),
    "complex_offset": (2e-3, 5e-3),
    "stripes_low_a": (2e-3, 5e-3),
}
#: Kinect v2 modulation frequencies of the three P0 planes, Hz
KINECT_FREQS = (80e6, 16e6, 120e6)
KINECT_P0 = (
    Path(__file__).resolve().parents[1]
    / "tests/data/real/kinect_v2_p0/p0tables_3x424x512_u16le.dat"
)
_SUB = 3  # sub-samples per pixel side at depth edges (mixed pixels)


def split(seed: int) -> str:
    """``"dev"`` for seeds below :data:`HELD_OUT_START`, else ``"held_out"``."""
    if seed < 0:
        raise ValueError(f"seed must be >= 0, got {seed}")
    return "dev" if seed < HELD_OUT_START else "held_out"


def _rng(*parts) -> np.random.Generator:
    """A generator seeded by integers and names (names by CRC32, so stable across runs)."""
    key = [p if isinstance(p, int) else zlib.crc32(str(p).encode()) for p in parts]
    return np.random.default_rng(key)


# ----------------------------------------------------------------------------------------------
# ray casting: camera at the origin, x right, y down, z forward (world "up" is -y)


def _rot(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """Camera-to-world rotation: roll about z, then pitch about x (positive: looks down), yaw
    about y (positive: looks right)."""
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    rz = np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]])
    rx = np.array([[1, 0, 0], [0, cp, sp], [0, -sp, cp]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    return ry @ rx @ rz


class _Plane:
    """Plane ``n . p = n . p0`` (one-sided: seen from either side)."""

    def __init__(self, normal, point, albedo, texture=None):
        n = np.asarray(normal, float)
        self.n = n / np.linalg.norm(n)
        self.k = float(self.n @ np.asarray(point, float))
        self.albedo, self.texture = albedo, texture

    def hit(self, r):
        den = r @ self.n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = self.k / den
        t = np.where((np.abs(den) > 1e-12) & (t > 0), t, np.inf)
        return t, np.broadcast_to(self.n, r.shape)


class _Room:
    """Inside of a convex polyhedron given by planes with outward normals: the exit point."""

    def __init__(self, planes, albedos):
        self.planes, self.albedos = planes, albedos
        self.albedo, self.texture = None, None

    def hit(self, r):
        ts = []
        for p in self.planes:
            den = r @ p.n
            with np.errstate(divide="ignore", invalid="ignore"):
                t = p.k / den
            ts.append(np.where((den > 1e-12) & (t > 0), t, np.inf))
        ts = np.stack(ts)
        i = np.argmin(ts, 0)
        t = ts[i, np.arange(r.shape[0])]
        n = np.stack([p.n for p in self.planes])[i]
        self.last_albedo = np.asarray(self.albedos)[i]
        return t, n


class _Box:
    """Box of half-sizes ``half`` centred at ``centre``, turned by ``yaw`` about the vertical."""

    def __init__(self, centre, half, yaw, albedo):
        self.c = np.asarray(centre, float)
        self.h = np.asarray(half, float)
        cy, sy = np.cos(yaw), np.sin(yaw)
        self.R = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])  # box-to-world
        self.albedo, self.texture = albedo, None

    def hit(self, r):
        o = -self.c @ self.R  # origin in box frame
        d = r @ self.R
        with np.errstate(divide="ignore", invalid="ignore"):
            t1 = (-self.h - o) / d
            t2 = (self.h - o) / d
        tmin = np.where(np.isnan(t1), -np.inf, np.minimum(t1, t2))
        tmax = np.where(np.isnan(t1), np.inf, np.maximum(t1, t2))
        near = tmin.max(1)
        far = tmax.min(1)
        ok = (near <= far) & (near > 0)
        axis = np.argmax(tmin, 1)
        nb = np.zeros_like(d)
        rows = np.arange(d.shape[0])
        nb[rows, axis] = -np.sign(d[rows, axis])
        return np.where(ok, near, np.inf), nb @ self.R.T


class _Cylinder:
    """Vertical cylinder (axis along world y) at ``(x0, z0)``, radius ``rad``; seen from outside,
    or from inside (``inside=True``: a curved wall around the camera)."""

    def __init__(self, x0, z0, rad, albedo, inside=False, texture=None):
        self.x0, self.z0, self.rad, self.inside = x0, z0, rad, inside
        self.albedo, self.texture = albedo, texture

    def hit(self, r):
        dx, dz = r[:, 0], r[:, 2]
        a = dx * dx + dz * dz
        b = -2 * (dx * self.x0 + dz * self.z0)
        c = self.x0**2 + self.z0**2 - self.rad**2
        disc = b * b - 4 * a * c
        sq = np.sqrt(np.maximum(disc, 0))
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((-b + sq) if self.inside else (-b - sq)) / (2 * a)
        t = np.where((disc > 0) & (a > 1e-12) & (t > 0), t, np.inf)
        p = r * np.where(np.isfinite(t), t, 0)[:, None]
        n = np.stack([p[:, 0] - self.x0, np.zeros_like(t), p[:, 2] - self.z0], 1)
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        return t, n


def _texture(rng: np.random.Generator):
    """A random albedo texture as a function of world points (N, 3) -> (N,) in [0.05, 1]:
    sums of gratings, a checkerboard, discs and bars (printed posters, wood, tiles)."""
    kind = rng.choice(["gratings", "checker", "discs", "bars"])
    lo, hi = rng.uniform(0.05, 0.25), rng.uniform(0.6, 1.0)
    if kind == "gratings":
        ks = rng.normal(0, 1, (4, 3)) * rng.uniform(10, 60, (4, 1))
        ph = rng.uniform(0, 2 * np.pi, 4)

        def f(p):
            s = np.sin(p @ ks.T + ph).sum(1) / 4
            return lo + (hi - lo) * (0.5 + 0.5 * np.clip(s * 1.6, -1, 1))

    elif kind == "checker":
        size = rng.uniform(0.03, 0.15)

        def f(p):
            q = np.floor(p[:, 0] / size) + np.floor(p[:, 1] / size) + np.floor(p[:, 2] / size)
            return np.where(q % 2 == 0, lo, hi)

    elif kind == "discs":
        n = 60
        cen = rng.uniform(-2.5, 2.5, (n, 3)) * [1, 1, 2] + [0, 0, 2.5]
        rad = rng.uniform(0.03, 0.25, n)
        val = rng.uniform(lo, hi, n)

        def f(p):
            out = np.full(p.shape[0], (lo + hi) / 2)
            for c, r0, v in zip(cen, rad, val, strict=True):
                d2 = ((p[:, :2] - c[:2]) ** 2).sum(1)
                out = np.where(d2 < r0 * r0, v, out)
            return out

    else:
        period = rng.uniform(0.02, 0.2)
        duty = rng.uniform(0.2, 0.8)
        axis = rng.integers(0, 2)

        def f(p):
            frac = (p[:, axis] / period) % 1.0
            return np.where(frac < duty, hi, lo)

    return f


def _scene(family: str, rng: np.random.Generator):
    """One scene: (camera rotation, primitives)."""
    if family == "still":
        family = str(rng.choice(["boxes", "room_corner", "staircase", "cylinders"]))
    a = lambda: rng.uniform(0.25, 0.9)  # noqa: E731
    if family == "slanted_planes":
        tilt = np.radians(rng.uniform(0, 65))
        az = rng.uniform(0, 2 * np.pi)
        n = np.array([np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), -np.cos(tilt)])
        prims = [_Plane(n, [0, 0, rng.uniform(0.7, 3.5)], a())]
        if rng.random() < 0.4:  # a second plane behind, crossing it
            tilt2 = np.radians(rng.uniform(0, 50))
            az2 = rng.uniform(0, 2 * np.pi)
            n2 = [np.sin(tilt2) * np.cos(az2), np.sin(tilt2) * np.sin(az2), -np.cos(tilt2)]
            prims.append(_Plane(n2, [0, 0, rng.uniform(1.0, 4.5)], a()))
        return _rot(0, 0, rng.uniform(-0.1, 0.1)), prims
    if family == "boxes":
        h = rng.uniform(1.0, 1.6)
        back = rng.uniform(3.0, 5.5)
        prims = [_Plane([0, -1, 0], [0, h, 0], a()), _Plane([0, 0, -1], [0, 0, back], a())]
        for _ in range(rng.integers(2, 6)):
            half = rng.uniform([0.1, 0.1, 0.1], [0.45, 0.5, 0.45])
            c = [rng.uniform(-1.2, 1.2), h - half[1], rng.uniform(1.2, back - 0.5)]
            prims.append(_Box(c, half, rng.uniform(0, np.pi / 2), a()))
        R = _rot(rng.uniform(-0.3, 0.3), np.radians(rng.uniform(15, 40)), rng.uniform(-0.05, 0.05))
        return R, prims
    if family == "room_corner":
        xr, zb = rng.uniform(1.5, 3.5), rng.uniform(1.5, 3.5)
        h, top = rng.uniform(1.0, 1.7), rng.uniform(0.8, 1.5)
        planes = [
            _Plane([1, 0, 0], [xr, 0, 0], 0),
            _Plane([0, 0, 1], [0, 0, zb], 0),
            _Plane([0, 1, 0], [0, h, 0], 0),
            _Plane([0, -1, 0], [0, -top, 0], 0),
            _Plane([-1, 0, 0], [-2.0, 0, 0], 0),
            _Plane([0, 0, -1], [0, 0, -2.0], 0),
        ]
        albedos = [a(), a(), a(), a(), a(), a()]
        yaw = np.arctan2(xr, zb) + rng.uniform(-0.35, 0.35)
        R = _rot(yaw, np.radians(rng.uniform(-10, 25)), rng.uniform(-0.05, 0.05))
        return R, [_Room(planes, albedos)]
    if family == "staircase":
        h = rng.uniform(1.2, 1.7)
        rise, run = rng.uniform(0.14, 0.2), rng.uniform(0.24, 0.34)
        z0, width = rng.uniform(1.0, 2.0), rng.uniform(1.0, 2.5)
        n = rng.integers(5, 12)
        x0 = rng.uniform(-0.5, 0.5)
        prims = [_Plane([0, -1, 0], [0, h, 0], a()), _Plane([0, 0, -1], [0, 0, z0 + n * run], a())]
        alb = a()
        for i in range(n):
            zs, ze = z0 + i * run, z0 + n * run
            hy = (i + 1) * rise / 2
            prims.append(_Box([x0, h - hy, (zs + ze) / 2], [width / 2, hy, (ze - zs) / 2], 0, alb))
        R = _rot(rng.uniform(-0.4, 0.4), np.radians(rng.uniform(5, 35)), rng.uniform(-0.05, 0.05))
        return R, prims
    if family == "textured":
        tex = _texture(rng)
        if rng.random() < 0.6:
            tilt = np.radians(rng.uniform(0, 45))
            az = rng.uniform(0, 2 * np.pi)
            nrm = [np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), -np.cos(tilt)]
            prim = _Plane(nrm, [0, 0, rng.uniform(0.8, 3.0)], 1.0, texture=tex)
        else:  # a gently curved wall
            rad = rng.uniform(4.0, 10.0)
            prim = _Cylinder(0.0, rng.uniform(0.8, 3.0) + rad, rad, 1.0, texture=tex)
        return _rot(rng.uniform(-0.2, 0.2), rng.uniform(-0.2, 0.2), rng.uniform(-0.1, 0.1)), [prim]
    if family == "cylinders":
        back = rng.uniform(3.0, 5.5)
        if rng.random() < 0.35:  # inside a curved wall
            rad = rng.uniform(2.0, 4.0)
            prims = [_Cylinder(0.0, rng.uniform(-0.5, 1.0), rad, a(), inside=True)]
        else:
            prims = [_Plane([0, 0, -1], [0, 0, back], a())]
            for _ in range(rng.integers(1, 4)):
                rad = rng.uniform(0.15, 1.2)
                z = rng.uniform(1.0 + rad, back - rad + 0.3)
                prims.append(_Cylinder(rng.uniform(-1.0, 1.0), z, rad, a()))
        return _rot(rng.uniform(-0.2, 0.2), np.radians(rng.uniform(-4, 4)), 0.0), prims
    raise ValueError(f"unknown scene family {family!r}; known: {list(FAMILIES)}")


def _cast(prims, r_world):
    """Closest hit of rays (N, 3): t (N,), unit normal (N, 3), albedo (N,)."""
    n_rays = r_world.shape[0]
    t = np.full(n_rays, np.inf)
    nrm = np.zeros((n_rays, 3))
    alb = np.zeros(n_rays)
    for p in prims:
        tp, npr = p.hit(r_world)
        closer = tp < t
        if not closer.any():
            continue
        t = np.where(closer, tp, t)
        nrm[closer] = npr[closer]
        if isinstance(p, _Room):
            alb[closer] = p.last_albedo[closer]
        elif p.texture is not None:
            pts = r_world[closer] * tp[closer, None]
            alb[closer] = p.albedo * p.texture(pts)
        else:
            alb[closer] = p.albedo
    return t, nrm, alb


class _Camera:
    """Pinhole intrinsics of one camera."""

    def __init__(self, h, w, hfov):
        self.h, self.w = h, w
        self.f = (w / 2) / np.tan(hfov / 2)

    def rays(self, dy, dx):
        """Camera rays (z = 1) through pixel centres shifted by (dy, dx) pixels: (H*W, 3)."""
        yy, xx = np.mgrid[0 : self.h, 0 : self.w].astype(float)
        x = (xx + dx - (self.w - 1) / 2) / self.f
        y = (yy + dy - (self.h - 1) / 2) / self.f
        return np.stack([x, y, np.ones_like(x)], -1).reshape(-1, 3)


def _render(cam, R, prims, f_mod, gain):
    """Noise-free measurement of one scene.

    Returns true depth Z (H, W) (NaN: no return in range), the clean phasor ``a e^{j phi}``
    (H, W) complex (mixed over sub-pixels at depth edges), the centre ray norms (H, W) and the
    mask of mixed (flying) pixels."""
    h, w = cam.h, cam.w
    rng_max = 0.95 * C_LIGHT / (2 * f_mod)

    def measure(r_cam):
        t, nrm, alb = _cast(prims, r_cam @ R.T)
        norm = np.linalg.norm(r_cam, axis=1)
        d = t * norm  # radial distance
        cos = np.abs((nrm * (r_cam @ R.T)).sum(1)) / norm
        ok = np.isfinite(d) & (d < rng_max)
        with np.errstate(invalid="ignore", over="ignore"):
            amp = np.where(ok, gain * alb * cos / np.where(ok, d, 1) ** 2, 0.0)
        phi = 4 * np.pi * f_mod * np.where(ok, d, 0) / C_LIGHT
        return np.where(ok, t, np.nan), d, amp * np.exp(1j * phi), ok

    r0 = cam.rays(0, 0)
    z, d, ph, ok = measure(r0)
    z, d, ph, ok = (v.reshape(h, w) for v in (z, d, ph, ok))
    norm0 = np.linalg.norm(r0, axis=1).reshape(h, w)
    # candidates for mixing: a neighbour at another depth or without a return
    zf = np.where(ok, d, -1.0)
    pad = np.pad(zf, 1, mode="edge")
    cand = np.zeros((h, w), bool)
    for sy in (-1, 0, 1):
        for sx in (-1, 0, 1):
            nb = pad[1 + sy : 1 + sy + h, 1 + sx : 1 + sx + w]
            cand |= np.abs(nb - zf) > 0.01
    flying = np.zeros((h, w), bool)
    if cand.any():
        idx = np.flatnonzero(cand)
        offs = (np.arange(_SUB) - (_SUB - 1) / 2) / _SUB
        acc = np.zeros(idx.size, complex)
        dmin = np.full(idx.size, np.inf)
        dmax = np.full(idx.size, -np.inf)
        for oy in offs:
            for ox in offs:
                _, ds, ps, oks = measure(cam.rays(oy, ox)[idx])
                acc += ps
                dmin = np.where(oks, np.minimum(dmin, ds), dmin)
                dmax = np.where(oks, np.maximum(dmax, ds), dmax)
        acc /= _SUB * _SUB
        # mixed: the returns' phasor sum moves the measured distance off the centre's (on a
        # smooth surface, even a steep one, the sum stays at the centre's distance)
        d_c = d.reshape(-1)[idx]
        d_mix = (np.angle(acc) % (2 * np.pi)) * C_LIGHT / (4 * np.pi * f_mod)
        mixed = ok.reshape(-1)[idx] & (dmax - dmin > 0.02) & (np.abs(d_mix - d_c) > 0.003)
        flat_ph, flat_fly = ph.reshape(-1), flying.reshape(-1)
        flat_ph[idx[mixed]] = acc[mixed]
        flat_fly[idx[mixed]] = True
    return z, ph, norm0, flying


# ----------------------------------------------------------------------------------------------
# fixed patterns


@lru_cache(maxsize=3)
def _kinect_fine(plane: int) -> np.ndarray:
    """Fine structure of one Kinect v2 P0 plane, metres, (424, 512)."""
    raw = np.fromfile(KINECT_P0, "<u2")
    if raw.size != 3 * 424 * 512:
        raise ValueError(f"{KINECT_P0}: expected 3 x 424 x 512 uint16, got {raw.size} values")
    p = raw.reshape(3, 424, 512)[plane].astype(float) * (2 * np.pi / 65536)
    # the tables hold ~pi offsets between alternating rows: fold phases mod pi, centre them
    z2 = np.exp(2j * p)
    ph = np.angle(z2 * np.exp(-1j * np.angle(z2.mean()))) / 2
    h, w = ph.shape
    yy, xx = np.mgrid[0:h, 0:w]
    u, v = (xx - w / 2) / (w / 2), (yy - h / 2) / (h / 2)
    basis = np.stack([(u**i * v**j).ravel() for i in range(5) for j in range(5 - i)], 1)
    coef = np.linalg.lstsq(basis, ph.ravel(), rcond=None)[0]
    fine = ph - (basis @ coef).reshape(h, w)
    fine = np.clip(fine, *np.percentile(fine, [0.1, 99.9]))  # a few defective table entries
    return fine * C_LIGHT / (4 * np.pi * KINECT_FREQS[plane])


def _pattern(kind: str, h: int, w: int, rng: np.random.Generator, f_mod: float):
    """(pattern (H, W) metres, complex offset (H, W) counts, stated RMS metres)."""
    offset = np.zeros((h, w), complex)
    if kind == "none":
        return np.zeros((h, w)), offset, 0.0
    rms = float(rng.uniform(*RMS_RANGE[kind]))
    if kind == "columns":
        p = np.broadcast_to(rng.normal(0, 1, w), (h, w))
    elif kind == "rows":
        p = np.broadcast_to(rng.normal(0, 1, (h, 1)), (h, w))
    elif kind == "stripes":
        x = np.arange(w)
        a1 = rng.uniform(0.5, 1.0)
        a2 = rng.uniform(0.3, 1.0)
        s = a1 * np.cos(2 * np.pi * x / 3 + rng.uniform(0, 2 * np.pi)) + a2 * np.cos(np.pi * x)
        p = np.broadcast_to(s, (h, w))
    elif kind == "kinect_p0":
        fine = _kinect_fine(int(rng.integers(0, 3)))
        y0 = int(rng.integers(0, fine.shape[0] - h + 1)) if h <= fine.shape[0] else 0
        x0 = int(rng.integers(0, fine.shape[1] - w + 1)) if w <= fine.shape[1] else 0
        if h > fine.shape[0] or w > fine.shape[1]:
            raise ValueError(f"kinect_p0 needs frames up to 424 x 512, got {h} x {w}")
        p = fine[y0 : y0 + h, x0 : x0 + w]
    elif kind in COMPLEX_KINDS:
        if kind == "complex_offset":
            col = rng.normal(0, 1, w) + 1j * rng.normal(0, 1, w)
            pix = rng.normal(0, 1, (h, w)) + 1j * rng.normal(0, 1, (h, w))
            c = col[None, :] + 0.3 * pix
            c = c - c.mean()
        else:  # column stripes of the correlation samples: one phase psi for all columns
            x = np.arange(w)
            s = rng.uniform(0.5, 1.0) * np.cos(2 * np.pi * x / 3 + rng.uniform(0, 2 * np.pi))
            s = s + rng.uniform(0.3, 1.0) * np.cos(np.pi * x)
            c = np.broadcast_to((s - s.mean()) * np.exp(1j * rng.uniform(0, 2 * np.pi)), (h, w))
            c = np.array(c)
        m_per_rad = C_LIGHT / (4 * np.pi * f_mod)
        c *= rms * np.sqrt(2) * A_REF / (m_per_rad * np.sqrt(np.mean(np.abs(c) ** 2)))
        return m_per_rad * np.angle(1 + c / A_REF), c, rms
    else:
        raise ValueError(f"unknown pattern kind {kind!r}; known: {list(PATTERNS)}")
    p = np.array(p, float)
    p -= p.mean()
    p *= rms / np.sqrt(np.mean(p**2))
    return p, offset, rms


# ----------------------------------------------------------------------------------------------
# the folder


def make_folder(
    out_dir,
    scene_family: str,
    pattern_kind: str,
    seed: int,
    n_frames: int = 6,
    height: int | None = None,
    width: int | None = None,
) -> dict:
    """Write ``out_dir/frames/<stem>_depth.png`` + ``_amplitude.png`` per frame and
    ``out_dir/truth.npz``; return the truth (see the module docstring).

    The scene depends on (``seed``, ``scene_family``), the pattern on (``seed``,
    ``pattern_kind``), so one seed gives the same scenes under every pattern kind. Frame size:
    ``height`` x ``width`` if given, else one of :data:`SIZES` drawn from (``seed``,
    ``scene_family``)."""
    if scene_family not in FAMILIES:
        raise ValueError(f"unknown scene family {scene_family!r}; known: {list(FAMILIES)}")
    if pattern_kind not in PATTERNS:
        raise ValueError(f"unknown pattern kind {pattern_kind!r}; known: {list(PATTERNS)}")
    if n_frames < 1:
        raise ValueError(f"n_frames must be >= 1, got {n_frames}")
    cam_rng = _rng(seed, "camera")
    h0, w0 = SIZES[int(_rng(seed, "size", scene_family).integers(0, len(SIZES)))]
    height, width = height or h0, width or w0
    h, w = int(height), int(width)
    f_mod = float(cam_rng.choice([15e6, 20e6, 20e6]))  # CamCube-class: 20 MHz, 7.5 m
    m_per_rad = C_LIGHT / (4 * np.pi * f_mod)
    cam = _Camera(h, w, np.radians(cam_rng.uniform(55, 75)))
    bright = cam_rng.random() < 0.2
    a_med = cam_rng.uniform(300, 1200) if bright else cam_rng.uniform(40, 220)
    sd_med = cam_rng.uniform(1.2e-3, 4.5e-3)  # depth noise sd at the median amplitude
    background = a_med * cam_rng.uniform(1.0, 4.0)  # ambient + dark signal, counts
    a_min = cam_rng.uniform(12, 25)
    a_sat = 4095.0
    prnu = 1 + 0.01 * cam_rng.normal(0, 1, (h, w))  # EMVA 1288 PRNU of the amplitude, 1 %
    k_noise = sd_med * a_med / np.sqrt(a_med + background)

    pattern, offset, rms = _pattern(pattern_kind, h, w, _rng(seed, "pattern", pattern_kind), f_mod)
    scene_rng = _rng(seed, "scene", scene_family)
    noise_rng = _rng(seed, "noise", scene_family, pattern_kind)

    keys = ("depth", "amplitude", "sd", "pattern_frames", "observed", "noise", "valid", "flying")
    out = {k: [] for k in keys}
    gain = None
    scene = None
    amp_files = []
    for _ in range(n_frames):
        if scene is None or scene_family != "still":
            R, prims = _scene(scene_family, scene_rng)
            scene = _render(cam, R, prims, f_mod, 1.0)
            if gain is None:  # exposure set once per camera, on its first scene
                a1 = np.abs(scene[1])
                gain = a_med / np.median(a1[a1 > 0]) if (a1 > 0).any() else 1.0
        z, ph, norm0, flying = scene
        ph = ph * (gain * prnu)
        amp = np.abs(ph)
        hit = np.isfinite(z)
        # clean phase of the pixel centre, or of the mixture at flying pixels
        phi_true = np.where(hit, 4 * np.pi * f_mod * np.where(hit, z, 0) * norm0 / C_LIGHT, 0.0)
        phi_clean = np.where(flying, np.angle(ph) % (2 * np.pi), phi_true)
        with np.errstate(divide="ignore", invalid="ignore"):
            z_clean = phi_clean * m_per_rad / norm0
            if pattern_kind in COMPLEX_KINDS:
                zc = np.where(amp > 0, amp, 1.0) * np.exp(1j * phi_clean) + offset
                dphi = np.angle(zc * np.exp(-1j * phi_clean))
                pat = np.where(amp > 0, dphi * m_per_rad / norm0, 0.0)
                amp_meas_clean = np.abs(zc)
            else:
                pat = pattern.copy()
                amp_meas_clean = amp
            sd = np.where(amp > 0, k_noise * np.sqrt(amp + background) / amp, np.inf)
        noise = noise_rng.normal(0, 1, (h, w)) * np.where(np.isfinite(sd), sd, 0)
        # amplitude noise: the phasor's component noise, sd_phase * A (Frank et al. 2009)
        amp_noise = noise_rng.normal(0, 1, (h, w)) * np.where(np.isfinite(sd), sd, 0)
        amp_meas = amp_meas_clean + amp_noise / m_per_rad * amp_meas_clean
        observed = z_clean + pat + noise
        valid = hit & (amp_meas >= a_min) & (amp_meas_clean < a_sat) & (observed > 0)
        observed = np.where(valid, observed, np.nan)
        amp_store = np.clip(np.where(amp_meas_clean >= a_sat, a_sat, amp_meas), 0, a_sat)
        out["depth"].append(z)
        out["amplitude"].append(amp)
        out["sd"].append(np.where(np.isfinite(sd), sd, np.nan))
        out["pattern_frames"].append(pat)
        out["observed"].append(observed)
        out["noise"].append(noise)
        out["valid"].append(valid)
        out["flying"].append(flying & valid)
        amp_files.append(amp_store)

    truth = {k: np.stack(out[k]) for k in keys}
    stems = np.array([f"frame_{i:03d}" for i in range(n_frames)])
    truth.update(
        pattern=pattern,
        offset=offset,
        ray_norm=norm0,
        pattern_rms=np.float64(rms),
        f_mod=np.float64(f_mod),
        a_ref=np.float64(A_REF),
        a_min=np.float64(a_min),
        a_sat=np.float64(a_sat),
        background=np.float64(background),
        family=np.array(scene_family),
        pattern_kind=np.array(pattern_kind),
        seed=np.int64(seed),
        stems=stems,
    )
    _write(Path(out_dir), truth, np.stack(amp_files))
    return truth


def _write(out_dir: Path, truth: dict, amp_store: np.ndarray) -> None:
    import torch

    from tof_fpn_torch.io import write_pair

    frames = out_dir / "frames"
    frames.mkdir(parents=True, exist_ok=True)
    for i, stem in enumerate(truth["stems"]):
        obs = np.where(truth["valid"][i], truth["observed"][i], np.nan)
        depth_mm = np.where(np.isfinite(obs), np.clip(np.round(obs * 1000), 1, 65535), 0)
        depth = torch.from_numpy(np.where(depth_mm > 0, depth_mm / 1000, np.nan))
        amp = torch.from_numpy(np.round(amp_store[i]))
        write_pair(
            frames / f"{stem}_depth.png",
            depth[None, None],
            amp[None, None],
            frames / f"{stem}_amplitude.png",
        )
    np.savez_compressed(out_dir / "truth.npz", **truth)


def load_truth(out_dir) -> dict:
    """The truth saved by :func:`make_folder` in ``out_dir/truth.npz``."""
    with np.load(Path(out_dir) / "truth.npz") as f:
        return {k: f[k] for k in f.files}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", help="output directory")
    ap.add_argument("--family", choices=FAMILIES)
    ap.add_argument("--pattern", choices=PATTERNS)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--height", type=int, help="frame height (default: drawn from the seed)")
    ap.add_argument("--width", type=int, help="frame width (default: drawn from the seed)")
    ap.add_argument("--all", action="store_true", help="every family x every pattern, one seed")
    args = ap.parse_args(argv)
    size = (args.height, args.width)
    if args.all:
        if split(args.seed) != "dev":
            ap.error("--all writes dev seeds only")
        for fam in FAMILIES:
            for pat in PATTERNS:
                t = make_folder(
                    Path(args.out) / f"{fam}__{pat}", fam, pat, args.seed, args.frames, *size
                )
                print(f"{fam:15s} {pat:15s} {t['depth'].shape} rms={float(t['pattern_rms']):.4f}")
        return 0
    if args.family is None or args.pattern is None:
        ap.error("give --family and --pattern, or --all")
    t = make_folder(args.out, args.family, args.pattern, args.seed, args.frames, *size)
    print(f"{args.out}: {t['depth'].shape}, split {split(args.seed)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
