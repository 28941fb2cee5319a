"""ToF recordings with physical effects whose forms are taken from the literature (the dev part).

An outside generator for the diagnosis benchmark (``benchmarks/bench_literature.py``): it shares no
code with the package's simulator. NumPy/SciPy only.

The camera
----------
A continuous-wave (AMCW) ToF camera with N = 4 correlation samples per frame, as in R. Lange and P.
Seitz, "Solid-state time-of-flight range camera", IEEE J. Quantum Electronics 37(3), 2001 (the
four-bucket sampling of the correlation function and its decoding by the first DFT bin), and R.
Lange, "3D time-of-flight distance measurement with custom solid-state image sensors in
CMOS/CCD-technology", PhD thesis, Univ. Siegen, 2000, ch. 2 and 4 (demodulation, shot-noise limited
phase precision).

- pinhole camera, 70 deg horizontal field of view, the principal point in the centre; depth is the
  radial distance along the pixel's ray;
- active light: a co-located source; the photo-electrons of the modulated light at a Lambertian
  point are ``K rho cos(theta_inc) / r**2`` (the source's 1/r^2, the surface radiance independent of
  the viewing distance); ambient (indoor) light ``E_amb ~ rho``; dark charge per sample;
- correlation sample k (theta_k = k pi / 2):
  ``mu_k = E_amb + E_dark + E_act (1 + m c(phi - theta_k))`` with ``c = cos`` for the ideal camera and
  ``phi = 4 pi f r / c0``, demodulation contrast m = 0.75;
- photon-transfer chain (EMVA Standard 1288, Release 4.0, 2021, sec. 2 "Sensor model": Poisson
  electrons, full-well saturation, conversion gain K in DN/e-, dark offset, read noise, ADC
  quantisation): electrons ~ Poisson(mu_k), clipped at the full well (110 ke-), DN = 0.5 DN/e- *
  electrons + 256 DN black level + read noise (3 DN rms), rounded and clipped to 16 bit [0, 65535];
- decoding by the first DFT bin: ``Z = sum_k raw_k exp(i theta_k)``, phase = arg Z in [0, 2 pi),
  depth = phase c0 / (4 pi f) in [0, R), R = c0 / (2 f) = 7.49 m at f = 20 MHz, amplitude = |Z| / 2 DN;
  depth is NaN where the amplitude is below 3 DN (the camera's validity threshold);
- auto-exposure: the exposure makes the brightest noiseless sample 60 % of the full well, so nulls
  never saturate.

Every planted effect has a magnitude parameter and is reported in ``truth`` with a size in physical
units and ``truth["stats"]``: the RMS change it makes to depth and amplitude (noiseless renders with
and without the effect, over the pixels it touches) against the camera's noise there (the median
per-pixel temporal std over T frames, divided by sqrt(T) -- the temporal-mean noise -- except for
effects that change from frame to frame, which are compared with the per-frame noise);
``visibility`` is the larger of the depth and amplitude ratios. Where a form's size in its own
units would depend on the scene's signal level (fixed offsets in DN, phase maps, drifts, jitter),
its magnitude is drawn as a multiple of the camera's noise at the median pixel and reported in
physical units; the docstrings say which. Section numbers in the citations are given as
remembered by the author of this module, the works themselves are the reference.

Forms (dev); each form's docstring cites its source:

- saturation: ``adc_clip``, ``well_prnu``, ``log_knee``
- fpn_pattern: ``column_adc_offsets``, ``row_offsets``, ``dsnu_tap_map``, ``column_1f_phase``,
  ``kinect_p0``
- amplitude_bias: ``lindner_kolb_log``, ``weakest_pixels``, ``exp_decay``
- cyclic_error: ``square_wave``, ``triangular_correlation``
- pixel_gain: ``prnu_white``, ``column_gain``
- impulsive_pixels: ``hot_pixels``, ``dark_rts``
- vignetting: ``cos4_lens``, ``led_lambertian``
- temporal_drift: ``warmup_exp``, ``thermal_gradient``
- flying_pixels: ``pixel_footprint_mix``, ``lens_psf_gaussian``
- multipath: ``specular_floor``, ``diffuse_interreflection``
- noise_floor: ``gaussian_phase_jitter``, ``tap_timing_jitter``
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy import ndimage

C0 = 299_792_458.0
F_MOD = 20e6
N_PHASES = 4
THETA = np.arange(N_PHASES) * (2 * np.pi / N_PHASES)
CONV_GAIN = 0.5  # DN per electron
FULL_WELL = 110_000.0  # electrons
BLACK_DN = 256.0
READ_NOISE_DN = 3.0
ADC_MAX = 65535.0
DARK_E = 50.0  # electrons per sample
MOD_CONTRAST = 0.75
AMP_MIN_DN = 3.0
HFOV_DEG = 70.0
BASE_INTEGRATION_US = 1000.0
AE_TARGET = 0.6  # brightest noiseless sample / full well
RANGE_M = C0 / (2 * F_MOD)
M_PER_RAD = C0 / (4 * np.pi * F_MOD)
SOURCE = "benchmarks/literature_generator.py"
PART_CODES = {"dev": 0, "heldout": 1, "heldout2": 2}
P0_FILE = (
    Path(__file__).resolve().parents[1]
    / "tests/data/real/kinect_v2_p0/p0tables_3x424x512_u16le.dat"
)


# ----------------------------------------------------------------------------------------------
# scenes: primitives, ray casting
# ----------------------------------------------------------------------------------------------


def _const(rho):
    return lambda p: np.full(p.shape[0], float(rho))


def _checker(rho1, rho2, size, axes=(0, 1)):
    def tex(p):
        a = np.floor(p[:, axes[0]] / size) + np.floor(p[:, axes[1]] / size)
        return np.where(np.mod(a, 2) == 0, rho1, rho2)

    return tex


def _stripes(rho1, rho2, period, axis=0):
    def tex(p):
        return np.where(np.mod(p[:, axis], period) < period / 2, rho1, rho2)

    return tex


def _value_noise(rng, lo, hi, cell, axes=(0, 1)):
    """Smooth random texture: a random grid (cell metres) interpolated bilinearly."""
    grid = rng.uniform(lo, hi, size=(64, 64))

    def tex(p):
        u = p[:, axes[0]] / cell + 32.0
        v = p[:, axes[1]] / cell + 32.0
        return ndimage.map_coordinates(grid, [u, v], order=1, mode="wrap")

    return tex


def _posters(base, rects):
    """A wall with rectangles ((u0, u1, v0, v1, rho) on axes 0, 1) of other reflectance."""

    def tex(p):
        r = base(p)
        for u0, u1, v0, v1, rho in rects:
            inside = (p[:, 0] >= u0) & (p[:, 0] <= u1) & (p[:, 1] >= v0) & (p[:, 1] <= v1)
            r = np.where(inside, rho, r)
        return r

    return tex


@dataclass
class Plane:
    point: tuple
    normal: tuple
    tex: Callable

    def hit(self, o, d):
        n = np.asarray(self.normal, float)
        n = n / np.linalg.norm(n)
        dn = d @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((np.asarray(self.point, float) - o) @ n) / dn
        t = np.where((t > 1e-6) & np.isfinite(t), t, np.inf)
        normal = np.broadcast_to(n, d.shape)
        normal = np.where((dn > 0)[:, None], -normal, normal)
        return t, normal


@dataclass
class Sphere:
    center: tuple
    radius: float
    tex: Callable

    def hit(self, o, d):
        c = np.asarray(self.center, float)
        oc = o - c
        b = d @ oc
        disc = b * b - (oc @ oc - self.radius**2)
        sq = np.sqrt(np.maximum(disc, 0.0))
        t = -b - sq
        t = np.where((disc > 0) & (t > 1e-6), t, np.inf)
        p = o + d * np.where(np.isfinite(t), t, 0.0)[:, None]
        normal = (p - c) / self.radius
        return t, normal


@dataclass
class Box:
    lo: tuple
    hi: tuple
    tex: Callable

    def hit(self, o, d):
        lo = np.asarray(self.lo, float)
        hi = np.asarray(self.hi, float)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / d
            t1 = (lo - o) * inv
            t2 = (hi - o) * inv
        tmin = np.minimum(t1, t2)
        tmax = np.maximum(t1, t2)
        tmin = np.nan_to_num(tmin, nan=-np.inf)
        tmax = np.nan_to_num(tmax, nan=np.inf)
        tn = tmin.max(axis=1)
        tf = tmax.min(axis=1)
        t = np.where((tn <= tf) & (tn > 1e-6), tn, np.inf)
        axis = tmin.argmax(axis=1)
        normal = np.zeros_like(d)
        normal[np.arange(len(d)), axis] = -np.sign(d[np.arange(len(d)), axis])
        return t, normal


@dataclass
class SceneSpec:
    name: str
    prims: list
    pitch_deg: float = 0.0
    floor_y: float | None = None  # the floor plane y = floor_y (camera at the origin, y up)
    side_x: float | None = None  # a side wall x = side_x
    extra: dict = field(default_factory=dict)


def _rays(h, w, pitch_deg=0.0, oversample=1, shift=(0.0, 0.0)):
    """Unit ray directions (h*s, w*s, 3) of the pinhole camera (x right, y up, z forward)."""
    s = oversample
    fx = (w / 2) / math.tan(math.radians(HFOV_DEG) / 2)
    u = (np.arange(w * s) + 0.5) / s - w / 2 + shift[1]
    v = (np.arange(h * s) + 0.5) / s - h / 2 + shift[0]
    uu, vv = np.meshgrid(u, v)
    d = np.stack([uu / fx, -vv / fx, np.ones_like(uu)], axis=-1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    a = -math.radians(pitch_deg)  # pitch < 0: looking down
    rot = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    return d @ rot.T


def cast(spec: SceneSpec, h, w, oversample=1, shift=(0.0, 0.0), origin=(0.0, 0.0, 0.0)):
    """Ray-cast the scene: dict with r (radial depth), rho, cos_inc, points, normals, dirs."""
    d = _rays(h, w, spec.pitch_deg, oversample, shift)
    shp = d.shape[:2]
    d = d.reshape(-1, 3)
    o = np.asarray(origin, float)
    best = np.full(len(d), np.inf)
    normal = np.zeros_like(d)
    idx = np.full(len(d), -1)
    for i, prim in enumerate(spec.prims):
        t, n = prim.hit(o, d)
        closer = t < best
        best = np.where(closer, t, best)
        normal = np.where(closer[:, None], n, normal)
        idx = np.where(closer, i, idx)
    if not np.isfinite(best).all():
        raise ValueError(f"scene {spec.name}: some rays hit nothing")
    p = o + d * best[:, None]
    rho = np.zeros(len(d))
    for i, prim in enumerate(spec.prims):
        sel = idx == i
        if sel.any():
            rho[sel] = prim.tex(p[sel])
    rho = np.clip(rho, 0.05, 0.95)
    cos_inc = np.clip(np.abs(np.sum(normal * d, axis=1)), 0.05, 1.0)
    return {
        "r": best.reshape(shp),
        "rho": rho.reshape(shp),
        "cos_inc": cos_inc.reshape(shp),
        "points": p.reshape(*shp, 3),
        "normals": normal.reshape(*shp, 3),
        "dirs": d.reshape(*shp, 3),
        "prim": idx.reshape(shp),
    }


def _room_box(rng, depth, half_w, floor, ceil, wall_tex, floor_tex):
    return [
        Plane((0, 0, depth), (0, 0, -1), wall_tex),
        Plane((0, floor, 0), (0, 1, 0), floor_tex),
        Plane((0, ceil, 0), (0, -1, 0), _const(rng.uniform(0.5, 0.8))),
        Plane((-half_w, 0, 0), (1, 0, 0), _value_noise(rng, 0.35, 0.7, 0.4, (2, 1))),
        Plane((half_w, 0, 0), (-1, 0, 0), _const(rng.uniform(0.3, 0.7))),
    ]


def scene_room(rng):
    """A room (back wall 4-5 m with posters, floor tiles, ceiling, side walls), boxes and spheres."""
    depth = rng.uniform(4.2, 5.0)
    half_w = rng.uniform(1.7, 2.1)
    floor = -rng.uniform(1.0, 1.3)
    ceil = rng.uniform(1.1, 1.35)
    rects = []
    for _ in range(rng.integers(2, 5)):
        u0 = rng.uniform(-1.6, 1.0)
        v0 = rng.uniform(-0.6, 0.6)
        rects.append(
            (
                u0,
                u0 + rng.uniform(0.3, 0.8),
                v0,
                v0 + rng.uniform(0.3, 0.6),
                rng.uniform(0.05, 0.95),
            )
        )
    wall = _posters(_const(rng.uniform(0.5, 0.85)), rects)
    prims = _room_box(
        rng, depth, half_w, floor, ceil, wall, _checker(0.2, rng.uniform(0.35, 0.6), 0.5, (0, 2))
    )
    for _ in range(rng.integers(1, 4)):
        x = rng.uniform(-1.2, 1.2)
        z = rng.uniform(1.5, 3.5)
        s = rng.uniform(0.3, 0.7)
        prims.append(
            Box(
                (x - s / 2, floor, z - s / 2),
                (x + s / 2, floor + rng.uniform(0.4, 1.2), z + s / 2),
                _const(rng.uniform(0.1, 0.9)),
            )
        )
    for _ in range(rng.integers(1, 3)):
        rad = rng.uniform(0.15, 0.35)
        prims.append(
            Sphere(
                (rng.uniform(-1.0, 1.0), rng.uniform(-0.5, 0.5), rng.uniform(1.2, 3.0)),
                rad,
                _const(rng.uniform(0.2, 0.95)),
            )
        )
    return SceneSpec("room", prims, floor_y=floor, side_x=half_w)


def scene_corridor(rng):
    """A corridor (1.6-2.2 m wide) ending at a wall 5-5.6 m away, doors on the walls."""
    half_w = rng.uniform(0.8, 1.1)
    floor = -rng.uniform(1.0, 1.2)
    ceil = rng.uniform(1.0, 1.3)
    depth = rng.uniform(5.0, 5.6)
    doors = []
    for _ in range(3):
        z0 = rng.uniform(1.0, 4.0)
        doors.append((z0, z0 + 0.9, rng.uniform(0.1, 0.9)))

    def side_tex(p):
        r = np.full(p.shape[0], 0.7)
        for z0, z1, rho in doors:
            r = np.where((p[:, 2] > z0) & (p[:, 2] < z1) & (p[:, 1] < 0.9), rho, r)
        return r

    prims = [
        Plane((0, 0, depth), (0, 0, -1), _stripes(0.3, 0.8, 0.5, 0)),
        Plane((0, floor, 0), (0, 1, 0), _checker(0.15, 0.45, 0.4, (0, 2))),
        Plane((0, ceil, 0), (0, -1, 0), _const(0.75)),
        Plane((-half_w, 0, 0), (1, 0, 0), side_tex),
        Plane((half_w, 0, 0), (-1, 0, 0), side_tex),
    ]
    if rng.uniform() < 0.7:
        x = rng.uniform(-0.4, 0.4)
        z = rng.uniform(2.0, 3.5)
        prims.append(
            Box(
                (x - 0.2, floor, z - 0.2),
                (x + 0.2, floor + 1.0, z + 0.2),
                _const(rng.uniform(0.2, 0.9)),
            )
        )
    return SceneSpec("corridor", prims, floor_y=floor, side_x=half_w)


def scene_tabletop(rng):
    """Camera pitched down 25-35 deg onto a table 0.7-0.9 m below with objects; a wall behind."""
    pitch = -rng.uniform(25, 35)
    table = -rng.uniform(0.7, 0.9)
    depth = rng.uniform(2.2, 3.0)
    prims = [
        Plane((0, table, 0), (0, 1, 0), _value_noise(rng, 0.2, 0.7, 0.15, (0, 2))),
        Plane((0, 0, depth), (0, 0, -1), _const(rng.uniform(0.4, 0.8))),
        Plane((-2.5, 0, 0), (1, 0, 0), _const(0.5)),
        Plane((2.5, 0, 0), (-1, 0, 0), _const(0.5)),
        Plane((0, 2.0, 0), (0, -1, 0), _const(0.6)),
    ]
    for _ in range(rng.integers(2, 5)):
        x = rng.uniform(-0.6, 0.6)
        z = rng.uniform(0.9, 1.9)
        if rng.uniform() < 0.5:
            rad = rng.uniform(0.06, 0.15)
            prims.append(Sphere((x, table + rad, z), rad, _const(rng.uniform(0.1, 0.95))))
        else:
            s = rng.uniform(0.1, 0.25)
            prims.append(
                Box(
                    (x - s, table, z - s),
                    (x + s, table + rng.uniform(0.1, 0.35), z + s),
                    _const(rng.uniform(0.1, 0.95)),
                )
            )
    return SceneSpec("tabletop", prims, pitch_deg=pitch, floor_y=table, side_x=2.5)


def scene_wall_target(rng):
    """A textured (checkerboard or stripes) wall 1.5-3 m away, slightly slanted, floor below."""
    dist = rng.uniform(1.5, 3.0)
    tilt = rng.uniform(-0.3, 0.3)
    n = np.array([math.sin(tilt), 0.0, -math.cos(tilt)])
    rho1, rho2 = rng.uniform(0.05, 0.3), rng.uniform(0.5, 0.95)
    tex = (
        _checker(rho1, rho2, rng.uniform(0.15, 0.35))
        if rng.uniform() < 0.5
        else _stripes(rho1, rho2, rng.uniform(0.2, 0.5), 0)
    )
    floor = -rng.uniform(1.0, 1.3)
    prims = [
        Plane((0, 0, dist), tuple(n), tex),
        Plane((0, floor, 0), (0, 1, 0), _const(0.3)),
        Plane((0, 1.6, 0), (0, -1, 0), _const(0.6)),
    ]
    if rng.uniform() < 0.6:
        prims.append(
            Sphere(
                (rng.uniform(-0.5, 0.5), rng.uniform(-0.3, 0.3), dist * 0.6),
                rng.uniform(0.12, 0.25),
                _const(rng.uniform(0.2, 0.9)),
            )
        )
    return SceneSpec("wall_target", prims, floor_y=floor)


def scene_objects_field(rng):
    """Spheres and boxes at 0.8-4 m in front of a far wall (4.8-5.2 m), floor below."""
    depth = rng.uniform(4.8, 5.2)
    floor = -rng.uniform(1.1, 1.3)
    prims = _room_box(
        rng,
        depth,
        2.4,
        floor,
        1.6,
        _value_noise(rng, 0.3, 0.9, 0.3),
        _const(rng.uniform(0.15, 0.4)),
    )
    for _ in range(rng.integers(4, 8)):
        z = rng.uniform(0.8, 4.0)
        x = rng.uniform(-0.6, 0.6) * z
        y = rng.uniform(-0.3, 0.3) * z
        rad = rng.uniform(0.08, 0.35)
        if rng.uniform() < 0.6:
            prims.append(Sphere((x, y, z), rad, _const(rng.uniform(0.05, 0.95))))
        else:
            prims.append(
                Box(
                    (x - rad, y - rad, z - rad),
                    (x + rad, y + rad, z + rad),
                    _checker(0.1, rng.uniform(0.5, 0.95), rad / 2, (0, 1)),
                )
            )
    return SceneSpec("objects_field", prims, floor_y=floor, side_x=2.4)


DEV_SCENES = {
    "room": scene_room,
    "corridor": scene_corridor,
    "tabletop": scene_tabletop,
    "wall_target": scene_wall_target,
    "objects_field": scene_objects_field,
}


# ----------------------------------------------------------------------------------------------
# the camera
# ----------------------------------------------------------------------------------------------


@dataclass
class Plan:
    """What a planted effect changes in the camera's chain (every field optional).

    Arrays broadcast to (T, N, H, W) (frames, samples, rows, columns) where they say so.
    """

    signal: Callable | None = None  # ctx -> {n: phasor (T?,N?,H,W)} (n=0: DC electrons)
    harmonics: dict | None = None  # correlation waveform c = sum_n a_n cos(n psi); default {1: 1}
    exposure: float = 1.0  # integration-time factor
    conv_gain: float = CONV_GAIN
    gain_active: np.ndarray | float = 1.0  # (T?,1,H,W), modulated light only (illumination)
    gain_light: np.ndarray | float = 1.0  # (T?,1,H,W), all photo-electrons (lens, PRNU)
    phase: np.ndarray | float = 0.0  # (T?,1,H,W) extra phase delay of the demodulation, rad
    theta: np.ndarray | float = 0.0  # (T?,N,H,W) extra sampling-phase error per sample, rad
    dark_extra: np.ndarray | float = 0.0  # (T?,N,H,W) extra mean dark electrons
    full_well: np.ndarray | float = FULL_WELL  # (H,W) per-pixel well capacity, electrons
    response: Callable | None = None  # electrons -> electrons (pixel non-linearity)
    offset_dn: np.ndarray | float = 0.0  # (T?,N,H,W) read-out offsets, DN
    raw_hook: Callable | None = None  # raw DN (T,N,H,W) -> raw DN, before the ADC clip
    temporal: bool = False  # the effect changes from frame to frame like noise


@dataclass
class Ctx:
    """The scene as the camera sees it (noiseless, no effect)."""

    spec: SceneSpec
    geom: dict
    h: int
    w: int
    t: int
    k_act: float  # photo-electrons scale of the modulated light (auto-exposure)
    amb: float  # ambient electrons at rho = 1
    e_act: np.ndarray  # (H,W) modulated-light electrons per sample (mean)
    e_amb: np.ndarray  # (H,W)
    phi: np.ndarray  # (H,W) true phase
    mu0: np.ndarray = None  # (N,H,W) noiseless mean electrons per sample, no effect
    amp0_dn: np.ndarray = None  # (H,W) noiseless amplitude, DN
    noise_mean_m: np.ndarray = None  # (H,W) predicted std of the T-frame mean depth, m


def electrons(spec, geom, k_act):
    return k_act * geom["rho"] * geom["cos_inc"] / geom["r"] ** 2


def make_ctx(spec: SceneSpec, h, w, t, rng) -> Ctx:
    geom = cast(spec, h, w)
    unit = geom["rho"] * geom["cos_inc"] / geom["r"] ** 2
    amb_frac = rng.uniform(0.05, 0.3)  # ambient at rho = 1 relative to the light at 2.5 m
    amb_unit = amb_frac / 2.5**2
    # auto-exposure: the brightest noiseless sample at AE_TARGET of the full well
    peak = np.max(unit * (1 + MOD_CONTRAST) + amb_unit * geom["rho"])
    k_act = (AE_TARGET * FULL_WELL - DARK_E) / peak
    ctx = Ctx(
        spec,
        geom,
        h,
        w,
        t,
        k_act,
        amb_unit * k_act,
        k_act * unit,
        amb_unit * k_act * geom["rho"],
        4 * np.pi * F_MOD * geom["r"] / C0,
    )
    ctx.mu0 = (
        ctx.e_amb + DARK_E + ctx.e_act * (1 + MOD_CONTRAST * np.cos(ctx.phi - THETA[:, None, None]))
    )
    ctx.amp0_dn = CONV_GAIN * MOD_CONTRAST * ctx.e_act
    var_dn = CONV_GAIN**2 * ctx.mu0 + READ_NOISE_DN**2 + 1 / 12
    sig_phi = np.sqrt(var_dn.sum(0) / 2) / (2 * ctx.amp0_dn)
    ctx.noise_mean_m = sig_phi * M_PER_RAD / math.sqrt(t)
    return ctx


def base_signal(ctx: Ctx, ns, geom=None, k_scale=1.0):
    """{n: E exp(i n phi)} for the direct path (n = 0: the DC electrons E)."""
    g = ctx.geom if geom is None else geom
    e = ctx.k_act * k_scale * g["rho"] * g["cos_inc"] / g["r"] ** 2
    phi = 4 * np.pi * F_MOD * g["r"] / C0
    return {n: (e if n == 0 else e * np.exp(1j * n * phi)) for n in ns}


def render(ctx: Ctx, plan: Plan, rng: np.random.Generator | None):
    """The camera's chain: (raw DN (T,N,H,W), depth (T,H,W), amplitude (T,H,W)).

    ``rng`` None: noiseless (means, no Poisson, no read noise, no quantisation).
    """
    t, h, w = ctx.t, ctx.h, ctx.w
    harm = plan.harmonics or {1: 1.0}
    ns = [0, *sorted(harm)]
    sig = plan.signal(ctx, ns) if plan.signal is not None else base_signal(ctx, ns)
    ga = np.asarray(plan.gain_active, float) * np.asarray(plan.gain_light, float) * plan.exposure
    dc = sig[0] * ga
    psi = np.asarray(plan.phase, float) - (THETA[:, None, None] + np.asarray(plan.theta, float))
    mu = ctx.e_amb * np.asarray(plan.gain_light, float) * plan.exposure + dc
    for n, a in harm.items():
        mu = mu + MOD_CONTRAST * a * np.real(sig[n] * ga * np.exp(1j * n * psi))
    mu = mu + DARK_E + np.asarray(plan.dark_extra, float)
    mu = np.broadcast_to(mu, (t, N_PHASES, h, w)).astype(np.float64)
    mu = np.maximum(mu, 0.0)
    e = rng.poisson(mu).astype(np.float64) if rng is not None else mu.copy()
    if plan.response is not None:
        e = plan.response(e)
    e = np.minimum(e, plan.full_well)
    dn = e * plan.conv_gain + BLACK_DN + np.asarray(plan.offset_dn, float)
    if rng is not None:
        dn = dn + rng.normal(0.0, READ_NOISE_DN, size=dn.shape)
    if plan.raw_hook is not None:
        dn = plan.raw_hook(dn)
    if rng is not None:
        dn = np.round(dn)
    raw = np.clip(dn, 0.0, ADC_MAX)
    depth, amp = decode(raw)
    return raw, depth, amp


def decode(raw):
    """First DFT bin of the N samples: depth in [0, R) (NaN below AMP_MIN_DN) and amplitude, DN."""
    z = np.tensordot(np.exp(1j * THETA), raw, axes=([0], [1]))
    amp = (np.abs(z) / 2).astype(np.float32).astype(np.float64)  # the stored precision
    phase = np.mod(np.angle(z), 2 * np.pi)
    depth = phase * M_PER_RAD
    depth = np.where((amp >= AMP_MIN_DN) & (depth > 0), depth, np.nan)
    return depth, amp


# ----------------------------------------------------------------------------------------------
# the dev forms
# ----------------------------------------------------------------------------------------------
# Each builder: (ctx, rng) -> (plan, magnitude, unit, size dict). The magnitude is drawn from the
# form's range by rng.


def _quantile_exposure(ctx, level_e, p):
    """Exposure factor so that a share p of the noiseless samples reaches level_e electrons."""
    sig = (ctx.mu0 - DARK_E).ravel()
    return float((np.mean(level_e) - DARK_E) / np.quantile(sig, 1 - p))


def _share_above(ctx, x, level):
    return float(np.mean(x * (ctx.mu0 - DARK_E) + DARK_E > level))


def sat_adc_clip(ctx, rng):
    """Hard ADC clip: the analog gain is 1 DN/e- (the ADC's 65535 DN = 65.5 ke- is reached before
    the 110 ke- well) and the integration time is raised until a share p of the samples reaches
    the ADC's full scale. EMVA Standard 1288 Rel. 4.0 (2021), sec. 2.1 (the saturation capacity
    is set by the ADC or the well, whichever comes first); R. Lange, PhD thesis, Univ. Siegen
    2000, sec. 4.2 (a saturated sample destroys the phase of the four-bucket estimate)."""
    p = rng.uniform(0.03, 0.10)
    gain = 1.0
    level = (ADC_MAX - BLACK_DN) / gain
    x = _quantile_exposure(ctx, level, p)
    return (
        Plan(exposure=x, conv_gain=gain),
        p,
        "share of samples clipped",
        {"clip_level_dn": ADC_MAX, "exposure_factor": x},
    )


def sat_well_prnu(ctx, rng):
    """Full-well clip with a per-pixel well capacity: FW_ij = FW (1 + s z_ij), z ~ N(0,1), s =
    3-8 %, clipped in electrons before the read noise (the sample stays noisy and below the
    ADC's range). EMVA 1288 Rel. 4.0, sec. 2.1 and 4.4 (saturation capacity; its spread over
    the pixels); J. R. Janesick, "Photon Transfer", SPIE Press 2007, ch. 5 (full well)."""
    p = rng.uniform(0.03, 0.10)
    s = rng.uniform(0.03, 0.08)
    fw = FULL_WELL * (1 + s * rng.standard_normal((ctx.h, ctx.w)))
    lo, hi = 1.0, 100.0
    for _ in range(50):
        mid = math.sqrt(lo * hi)
        if _share_above(ctx, mid, fw[None]) < p:
            lo = mid
        else:
            hi = mid
    return (
        Plan(exposure=hi, full_well=fw),
        p,
        "share of samples clipped",
        {"well_mean_e": FULL_WELL, "well_prnu": s, "exposure_factor": hi},
    )


def sat_log_knee(ctx, rng):
    """Soft knee: linear below the knee E_k, logarithmic above,
    ``E' = E_k + E_k s ln(1 + (E - E_k) / (E_k s))`` (compression s = 0.1-0.3), a share p of the
    samples above the knee. G. Storm, R. Henderson, J. E. D. Hurwitz, D. Renshaw, K. Findlater,
    M. Purcell, "Extended dynamic range from a combined linear-logarithmic CMOS image sensor",
    IEEE J. Solid-State Circuits 41(9), 2006, sec. II (the lin-log pixel response)."""
    p = rng.uniform(0.03, 0.10)
    s = rng.uniform(0.1, 0.3)
    knee = 0.5 * FULL_WELL
    x = _quantile_exposure(ctx, knee, p)
    ks = knee * s

    def resp(e):
        return np.where(e <= knee, e, knee + ks * np.log1p(np.maximum(e - knee, 0) / ks))

    return (
        Plan(exposure=x, response=resp),
        p,
        "share of samples above the knee",
        {"knee_e": knee, "compression": s, "exposure_factor": x},
    )


def noise_rad(ctx):
    """Per-pixel std of the T-frame mean phase (rad) of the effect-free camera, (H, W)."""
    return ctx.noise_mean_m / M_PER_RAD


def dn_for_visibility(ctx, v, factor):
    """The per-sample DN rms s of a fixed read-out offset whose phase error (rms ``factor * s /
    A`` at a pixel of amplitude A) is v times the temporal-mean noise at the median pixel."""
    return float(v / np.median(factor / (ctx.amp0_dn * noise_rad(ctx))))


def _complex_offset_taps(z):
    """Per-sample DN offsets o_k whose first DFT bin is the complex offset z (o_k = Re(z e^-i th_k)/2)."""
    return np.real(z[..., None, :, :] * np.exp(-1j * THETA)[:, None, None]) / 2


def fpn_column_adc_offsets(ctx, rng):
    """Column-parallel ADC offsets: every column's converter has its own offset per sample
    (per tap), the same in every frame; o_kj ~ N(0, s) DN, s chosen so that the phase error
    (rms s / (sqrt 2 A)) is 4-8 x the temporal-mean noise at the median pixel (s is reported,
    typically 10-60 DN of the 16-bit range). A. El Gamal and H. Eltoukhy, "CMOS image sensors",
    IEEE Circuits and Devices Magazine 21(3), 2005, sec. "Fixed pattern noise" (column FPN of
    column-parallel read-out); M. F. Snoeij, A. J. P. Theuwissen, K. A. A. Makinwa, J. H.
    Huijsing, "Multiple-ramp column-parallel ADC architectures for CMOS image sensors", IEEE JSSC
    42(12), 2007, sec. II (column offsets)."""
    v = rng.uniform(4.0, 8.0)
    s = dn_for_visibility(ctx, v, 1 / math.sqrt(2))
    off = s * rng.standard_normal((N_PHASES, 1, ctx.w))
    off = np.broadcast_to(off, (N_PHASES, ctx.h, ctx.w)).copy()
    return (
        Plan(offset_dn=off),
        s,
        "DN rms per sample",
        {"column_offset_rms_dn": s, "target_visibility": v},
    )


def fpn_row_offsets(ctx, rng):
    """Row offsets: a complex read-out offset per row (row-wise reset/driver coupling), added to
    the raw samples as o_k = Re(z_i exp(-i theta_k)) / 2, Re z_i, Im z_i ~ N(0, s) (phase error
    rms s / (2 A)), s set for 4-8 x the temporal-mean noise at the median pixel. El Gamal and
    Eltoukhy 2005 (above), sec. "Fixed pattern noise" (row FPN); EMVA 1288 Rel. 4.0, sec. 8.3
    (row and column non-uniformity in the spatial variance)."""
    v = rng.uniform(4.0, 8.0)
    s = dn_for_visibility(ctx, v, 0.5)
    z = s * (rng.standard_normal(ctx.h) + 1j * rng.standard_normal(ctx.h))
    z = np.broadcast_to(z[:, None], (ctx.h, ctx.w))
    return (
        Plan(offset_dn=_complex_offset_taps(z)),
        s,
        "DN rms per component",
        {"row_complex_offset_rms_dn": s * math.sqrt(2), "target_visibility": v},
    )


def fpn_dsnu_tap_map(ctx, rng):
    """Pixel DSNU per tap: each pixel's tap has its own dark offset (white, plus a weak vertical
    gradient), the same in every frame, o_kij ~ N(0, s) DN, s set for 4-8 x the temporal-mean
    noise at the median pixel. EMVA Standard 1288 Rel. 4.0 (2021), sec. 4.5 and 8 (DSNU: the
    spatial non-uniformity of the dark signal)."""
    v = rng.uniform(4.0, 8.0)
    s = dn_for_visibility(ctx, v, 1 / math.sqrt(2))
    off = s * rng.standard_normal((N_PHASES, ctx.h, ctx.w))
    yy = np.linspace(-1, 1, ctx.h)[:, None]
    off = off + rng.uniform(-1, 1, (N_PHASES, 1, 1)) * s * yy
    return Plan(offset_dn=off), s, "DN rms per sample", {"dsnu_rms_dn": s, "target_visibility": v}


def _pink_1d(rng, n, alpha=1.0):
    spec = rng.standard_normal(n // 2 + 1) + 1j * rng.standard_normal(n // 2 + 1)
    f = np.arange(n // 2 + 1, dtype=float)
    f[0] = 1.0
    spec = spec / f ** (alpha / 2)
    spec[0] = 0.0
    x = np.fft.irfft(spec, n)
    return x / x.std()


def fpn_column_1f_phase(ctx, rng):
    """Column phase offsets with a 1/f spectrum (a demodulation delay per column of the clock
    tree, same in every frame): phi_j with power spectrum ~ 1/f, rms s = 4-8 x the temporal-mean
    phase noise at the median pixel (typically 10-40 mrad). EMVA 1288
    Rel. 4.0, sec. 8.6 (non-white spatial spectra of the DSNU/PRNU); F. Mufti and R. Mahony,
    "Statistical analysis of signal measurement in time-of-flight cameras", ISPRS J. Photogramm.
    Remote Sens. 66(5), 2011 (per-pixel phase offsets as a fixed pattern)."""
    s = rng.uniform(4.0, 8.0) * float(np.median(noise_rad(ctx)))
    ph = s * _pink_1d(rng, ctx.w)
    return (
        Plan(phase=np.broadcast_to(ph[None, :], (ctx.h, ctx.w)).copy()),
        s,
        "rad rms",
        {"phase_rms_rad": s, "depth_rms_m": s * M_PER_RAD},
    )


def p0_fine_structure(h, w, rng, table=None):
    """A crop of a Kinect v2 P0 table's fine structure, radians (the smooth part removed).

    The table holds a per-pixel phase offset in units of 2 pi / 65536 (libfreenect2,
    src/cpu_depth_packet_processor.cpp: ``p0 * 0.000031 * M_PI``); its rows alternate by pi (the
    sensor's interleaved read-out), so the phase is taken modulo pi, then the smooth part (a
    Gaussian of 6 px) is removed.
    """
    a = np.fromfile(P0_FILE, dtype="<u2")
    if a.size != 3 * 424 * 512:
        raise ValueError(f"{P0_FILE}: expected 3*424*512 uint16, got {a.size}")
    a = a.reshape(3, 424, 512).astype(np.float64)
    k = int(rng.integers(0, 3)) if table is None else table
    v = np.mod(a[k], 32768.0)
    v = np.mod(v - np.median(v) + 16384.0, 32768.0) - 16384.0
    ph = v * 2 * np.pi / 65536.0
    ph = ph[2:-2, 4:-4]
    fine = ph - ndimage.gaussian_filter(ph, 6.0, mode="reflect")
    hh, ww = fine.shape
    if h > hh or w > ww:
        fine = ndimage.zoom(fine, (max(1.0, h / hh), max(1.0, w / ww)), order=1)
        hh, ww = fine.shape
    r0 = int(rng.integers(0, hh - h + 1))
    c0 = int(rng.integers(0, ww - w + 1))
    return fine[r0 : r0 + h, c0 : c0 + w].copy()


def fpn_kinect_p0(ctx, rng):
    """A real per-pixel phase-offset map: the fine structure of a Microsoft Kinect v2 factory P0
    table (tests/data/real/kinect_v2_p0), a crop at native resolution, smooth part removed,
    scaled to 4-8 x the temporal-mean phase noise at the median pixel (its native rms is 5-16
    mrad; the scale factor is the magnitude), as a phase delay in every frame.
    libfreenect2 (L. Xiang, F. Echtler, C. Kerl, T. Wiedemeyer, Lars, hanyazou, R. Gordon, F.
    Facioni, laborer2008, R. Wareham, et al., "libfreenect2: Release 0.2", Zenodo 2016,
    doi:10.5281/zenodo.50641), src/cpu_depth_packet_processor.cpp (the P0 tables subtracted from
    the phase); C. S. Bamji et al., "A 0.13 um CMOS system-on-chip for a 512x424 time-of-flight
    image sensor with multi-frequency photo-demodulation up to 130 MHz and 2 GS/s ADC", IEEE JSSC
    50(1), 2015 (the sensor)."""
    fine = p0_fine_structure(ctx.h, ctx.w, rng)
    scale = rng.uniform(4.0, 8.0) * float(np.median(noise_rad(ctx))) / float(fine.std())
    fine = fine * scale
    s = float(fine.std())
    return (
        Plan(phase=fine),
        scale,
        "x native P0 fine structure",
        {"phase_rms_rad": s, "depth_rms_m": s * M_PER_RAD},
    )


def _amp_bias_plan(ctx, rng, shape_fn):
    a = ctx.amp0_dn
    sign = 1.0 if rng.uniform() < 0.7 else -1.0
    return sign, shape_fn(a)


def ab_lindner_kolb_log(ctx, rng):
    """Intensity-related distance error, monotone in the amplitude: delta_d(A) = b ln(A_hi / A) /
    ln(A_hi / A_lo) (clipped at 0 above A_hi; A_lo, A_hi the 1st and 95th amplitude
    percentiles), b = 4-12 cm at the dark end. M. Lindner and A. Kolb, "Calibration of the
    intensity-related distance error of the PMD TOF-camera", Proc. SPIE 6764, Intelligent Robots
    and Computer Vision XXV, 2007, sec. 3 (the error decreases with the intensity; fitted there
    by a B-spline, here by a logarithm)."""
    b = rng.uniform(0.04, 0.12)
    a = ctx.amp0_dn
    lo, hi = np.percentile(a, [1, 95])
    shape = np.clip(np.log(hi / np.maximum(a, 1e-6)) / np.log(hi / lo), 0, None)
    sign = 1.0 if rng.uniform() < 0.7 else -1.0
    d = sign * b * shape
    return (
        Plan(phase=d / M_PER_RAD),
        b,
        "m at the 1st amplitude percentile",
        {"bias_max_m": float(np.abs(d).max()), "sign": sign},
    )


def ab_weakest_pixels(ctx, rng):
    """A bias carried only by the weakest q = 2-6 % of the pixels: delta_d = b (1 - A / A_q)^0.5
    for A < A_q (A_q the q-quantile of the amplitude), 0 above; b = 8-14 x the temporal-mean
    noise of those pixels. S. Fuchs and G. Hirzinger, "Extrinsic and depth calibration of
    ToF-cameras", CVPR 2008, sec. 4 (the distance error depends on the intensity, strongest at
    low intensity); T. Kahlmann, F. Remondino, H. Ingensand, "Calibration for increased accuracy
    of the range imaging camera SwissRanger", ISPRS Comm. V Symposium, 2006, sec. 4.3."""
    q = rng.uniform(0.02, 0.06)
    a = ctx.amp0_dn
    aq = np.quantile(a, q)
    weak = a < aq
    k = rng.uniform(8.0, 14.0)
    b = k * float(np.median(ctx.noise_mean_m[weak])) / 0.7
    shape = np.where(weak, np.sqrt(np.clip(1 - a / aq, 0, 1)), 0.0)
    sign = 1.0 if rng.uniform() < 0.7 else -1.0
    return (
        Plan(phase=sign * b * shape / M_PER_RAD),
        q,
        "share of pixels carrying the bias",
        {"bias_max_m": b, "amplitude_threshold_dn": float(aq), "sign": sign},
    )


def ab_exp_decay(ctx, rng):
    """A bias decaying exponentially with the amplitude: delta_d = b exp(-A / A0), A0 = 0.1-0.3 x
    the median amplitude, b = 8-20 cm. M. Lindner, I. Schiller, A. Kolb, R. Koch, "Time-of-flight
    sensor calibration for accurate range sensing", Computer Vision and Image Understanding
    114(12), 2010, sec. 4.2 (intensity-related error, largest for low amplitudes; the exponential
    shape is this generator's parametrisation)."""
    b = rng.uniform(0.08, 0.20)
    a0 = rng.uniform(0.1, 0.3) * float(np.median(ctx.amp0_dn))
    sign = 1.0 if rng.uniform() < 0.7 else -1.0
    d = sign * b * np.exp(-ctx.amp0_dn / a0)
    return Plan(phase=d / M_PER_RAD), b, "m at zero amplitude", {"a0_dn": a0, "sign": sign}


def ce_square_wave(ctx, rng):
    """Wiggling from square-wave modulation: c(psi) = cos psi + h (cos 3psi / 3 + cos 5psi / 5
    + cos 7psi / 7) (the odd harmonics of a square wave, h = 0.05-0.2 of the ideal square's); with
    4 samples the 3rd and 5th harmonics alias onto the fundamental and give a depth error of period
    R / 4. R. Lange, PhD thesis 2000, sec. 4.1.3 (harmonics and the four-bucket sampling); A. D.
    Payne, A. A. Dorrington, M. J. Cree, D. A. Carnegie, "Improved measurement linearity and
    precision for AMCW time-of-flight range imaging cameras", Applied Optics 49(23), 2010, sec. 2."""
    h = rng.uniform(0.05, 0.2)
    harm = {1: 1.0, 3: h / 3, 5: h / 5, 7: h / 7}
    return (
        Plan(harmonics=harm),
        h,
        "x the square wave's harmonics",
        {"a3": h / 3, "phase_error_peak_rad_approx": h / 3 + h / 5},
    )


def ce_triangular(ctx, rng):
    """Wiggling from a triangular correlation (square illumination x square demodulation):
    c(psi) = cos psi + h (cos 3psi / 9 + cos 5psi / 25 + cos 7psi / 49), h = 0.4-1 of the ideal
    triangle. M. Lindner and A. Kolb, "Lateral and depth calibration of PMD-distance sensors",
    ISVC 2006, LNCS 4292, sec. 3 (the systematic 'wiggling' error); H. Rapp, "Experimental and
    theoretical investigation of correlating TOF-camera systems", Diploma thesis, Univ.
    Heidelberg, 2007, ch. 3 (the correlation of square signals)."""
    h = rng.uniform(0.4, 1.0)
    harm = {1: 1.0, 3: h / 9, 5: h / 25, 7: h / 49}
    return Plan(harmonics=harm), h, "x the triangle's harmonics", {"a3": h / 9}


def pg_prnu_white(ctx, rng):
    """PRNU: a white per-pixel gain on the photo-electrons (active and ambient), 1 + s z, s =
    3-8 %. EMVA Standard 1288 Rel. 4.0, sec. 4.5 (PRNU)."""
    s = rng.uniform(0.03, 0.08)
    g = 1 + s * rng.standard_normal((ctx.h, ctx.w))
    return Plan(gain_light=g), s, "relative rms", {"prnu_rms": s}


def pg_column_gain(ctx, rng):
    """Column amplifier gain mismatch: one gain per column, 1 + s z_j, the same in every frame, s
    = 5-10 x the relative temporal-mean amplitude noise at the median pixel (typically 1-5 %). El Gamal and Eltoukhy, IEEE Circuits and Devices Magazine 21(3), 2005 (column
    gain FPN); EMVA 1288 Rel. 4.0, sec. 8.3 (column PRNU)."""
    s = rng.uniform(5.0, 10.0) * float(np.median(noise_rad(ctx)))
    g = 1 + s * rng.standard_normal((1, ctx.w))
    return (
        Plan(gain_light=np.broadcast_to(g, (ctx.h, ctx.w)).copy()),
        s,
        "relative rms",
        {"column_gain_rms": s},
    )


def imp_hot_pixels(ctx, rng):
    """Hot pixels: a share f = 0.3-1 % of the pixels with a large dark current in one or two taps
    (D = 2-20 ke- per sample, log-uniform), fixed in time, with its shot noise. J. Leung, G. H.
    Chapman, I. Koren, Z. Koren, "Statistical identification and analysis of defect development in
    digital imagers", Proc. SPIE 7250, 2009, sec. 2 (hot pixels: a dark-current offset growing
    with the exposure); EMVA 1288 Rel. 4.0, sec. 8.7 (defect pixels)."""
    f = rng.uniform(0.003, 0.01)
    n = max(1, int(round(f * ctx.h * ctx.w)))
    idx = rng.choice(ctx.h * ctx.w, n, replace=False)
    dark = np.zeros((N_PHASES, ctx.h * ctx.w))
    for i in idx:
        taps = rng.choice(N_PHASES, int(rng.integers(1, 3)), replace=False)
        dark[taps, i] = math.exp(rng.uniform(math.log(2000), math.log(20000)))
    return (
        Plan(dark_extra=dark.reshape(N_PHASES, ctx.h, ctx.w)),
        f,
        "share of pixels",
        {"n_pixels": n, "dark_e_range": [2000, 20000]},
    )


def imp_dark_rts(ctx, rng):
    """Dark-current random telegraph signal: a share f = 0.5-2 % of the pixels switch between two
    dark-current levels (in one tap) from frame to frame, a two-state Markov chain with switching
    probability 0.15-0.4 per frame, step D = 2-15 ke- per sample. I. H. Hopkins and G. R.
    Hopkinson, "Random telegraph signals from proton-irradiated CCDs", IEEE Trans. Nucl. Sci.
    40(6), 1993; X. Wang, P. R. Rao, A. Mierop, A. J. P. Theuwissen, "Random telegraph signal in
    CMOS image sensor pixels", IEDM 2006."""
    f = rng.uniform(0.005, 0.02)
    n = max(1, int(round(f * ctx.h * ctx.w)))
    idx = rng.choice(ctx.h * ctx.w, n, replace=False)
    dark = np.zeros((ctx.t, N_PHASES, ctx.h * ctx.w))
    for i in idx:
        tap = int(rng.integers(0, N_PHASES))
        step = math.exp(rng.uniform(math.log(2000), math.log(15000)))
        ps = rng.uniform(0.15, 0.4)
        state = int(rng.integers(0, 2))
        for ti in range(ctx.t):
            if rng.uniform() < ps:
                state = 1 - state
            dark[ti, tap, i] = state * step
    return (
        Plan(dark_extra=dark.reshape(ctx.t, N_PHASES, ctx.h, ctx.w), temporal=True),
        f,
        ("share of pixels"),
        {"n_pixels": n, "step_e_range": [2000, 15000]},
    )


def field_angle(ctx):
    d = _rays(ctx.h, ctx.w)
    return np.arccos(np.clip(d[..., 2], -1, 1))


def vig_cos4(ctx, rng):
    """Natural vignetting of the lens, cos^n of the field angle on all light reaching the pixel
    (n = 4 for the ideal thin lens; n = 1.5-4 here, 27-68 % fall-off in the corners). S. B. Kang
    and R. Weiss, "Can we calibrate a camera using an image of a flat, textureless Lambertian
    surface?", ECCV 2000, sec. 2 (the off-axis cos^4 law); B. K. P. Horn, "Robot Vision", MIT
    Press 1986, sec. 10.3."""
    n = rng.uniform(1.5, 4.0)
    v = np.cos(field_angle(ctx)) ** n
    return Plan(gain_light=v), n, "cos exponent", {"corner_falloff": float(1 - v.min())}


def vig_led_lambertian(ctx, rng):
    """The LED's radiation pattern on the modulated light only: I(theta) = cos^m theta with m =
    -ln 2 / ln cos(theta_half), half-intensity angle theta_half = 30-50 deg (a generalised
    Lambertian emitter). I. Moreno and C.-C. Sun, "Modeling the radiation pattern of LEDs",
    Optics Express 16(3), 2008, eq. (1)."""
    th = math.radians(rng.uniform(30.0, 50.0))
    m = -math.log(2) / math.log(math.cos(th))
    v = np.cos(field_angle(ctx)) ** m
    return (
        Plan(gain_active=v),
        math.degrees(th),
        "deg half-intensity angle",
        {"m": m, "corner_falloff": float(1 - v.min())},
    )


def td_warmup_exp(ctx, rng):
    """Warm-up: a global depth drift delta_d(t) = b (1 - exp(-t / tau)), tau = 4-12 frames, |b| =
    6-12 x the temporal-mean noise at the median pixel (typically 2-6 cm), with the LED's power
    drooping 2-5 % on the same curve. T. Kahlmann, F. Remondino, H.
    Ingensand, ISPRS Comm. V Symposium 2006, sec. 4.1 (distance drift during warm-up); F.
    Chiabrando, R. Chiabrando, D. Piatti, F. Rinaudo, "Sensors for 3D imaging: metric evaluation
    and calibration of a CCD/CMOS time-of-flight camera", Sensors 9(12), 2009, sec. 3.1."""
    b = rng.uniform(6.0, 12.0) * float(np.median(ctx.noise_mean_m))
    b *= 1 if rng.uniform() < 0.5 else -1
    tau = rng.uniform(4, 12)
    droop = rng.uniform(0.02, 0.05)
    s = 1 - np.exp(-np.arange(ctx.t) / tau)
    ph = (b * s / M_PER_RAD)[:, None, None, None]
    g = (1 - droop * s)[:, None, None, None]
    return (
        Plan(phase=ph, gain_active=g),
        abs(b),
        "m drift at the end",
        {"drift_m": b, "tau_frames": tau, "power_droop": droop},
    )


def td_thermal_gradient(ctx, rng):
    """A linear drift over the frames whose rate varies across the sensor (a temperature gradient
    from the illumination board): delta_d(t, x) = b t / (T-1) (0.5 + x / W), |b| = 6-12 x the
    temporal-mean noise at the median pixel (typically 2-6 cm). P.
    Fuersattel, S. Placht, M. Balda, C. Schaller, H. Hofmann, A. Maier, C. Riess, "A comparative
    error analysis of current time-of-flight sensors", IEEE Trans. Computational Imaging 2(1),
    2016, sec. IV-A (temperature/warm-up drift)."""
    b = rng.uniform(6.0, 12.0) * float(np.median(ctx.noise_mean_m))
    b *= 1 if rng.uniform() < 0.5 else -1
    tt = np.arange(ctx.t) / max(ctx.t - 1, 1)
    xx = np.linspace(0, 1, ctx.w)
    if rng.uniform() < 0.5:
        xx = xx[::-1]
    d = b * tt[:, None, None] * (0.5 + xx[None, None, :])
    return Plan(phase=(d / M_PER_RAD)[:, None]), abs(b), "m drift at the centre", {"b_m": b}


def _oversampled_signal(ctx, ns, s, blur_px=0.0, box=1.0):
    """The pixel's signal integrated over its footprint: s x s sub-rays per pixel, the complex
    signal optionally blurred (Gaussian, blur_px pixels), averaged over a box of `box` pixels."""
    g = cast(ctx.spec, ctx.h, ctx.w, oversample=s)
    sig = base_signal(ctx, ns, geom=g)
    out = {}
    for n, v in sig.items():
        if blur_px > 0:
            if np.iscomplexobj(v):
                v = ndimage.gaussian_filter(v.real, blur_px * s) + 1j * ndimage.gaussian_filter(
                    v.imag, blur_px * s
                )
            else:
                v = ndimage.gaussian_filter(v, blur_px * s)
        if box != 1.0:
            size = max(1, int(round(box * s)))
            if np.iscomplexobj(v):
                v = ndimage.uniform_filter(v.real, size) + 1j * ndimage.uniform_filter(v.imag, size)
            else:
                v = ndimage.uniform_filter(v, size)
        out[n] = v.reshape(ctx.h, s, ctx.w, s).mean(axis=(1, 3))
    return out


def fp_pixel_footprint_mix(ctx, rng):
    """Mixed pixels: each pixel integrates the complex return over a footprint of w = 1-2 pixels
    (fill factor, micro-lens spread), so a pixel on a depth edge sees both surfaces and reports a
    depth between them: Z = sum_i A_i exp(i phi_i). J. P. Godbaz, M. J. Cree, A. A. Dorrington,
    "Understanding and ameliorating mixed pixels and multipath interference in AMCW lidar", in
    TOF Range-Imaging Cameras (F. Remondino, D. Stoppa, eds.), Springer 2013, sec. 4.2."""
    wpx = rng.uniform(1.0, 2.0)

    def sig(c, ns):
        return _oversampled_signal(c, ns, 4, box=wpx)

    return Plan(signal=sig), wpx, "footprint width, px", {"footprint_px": wpx}


def fp_lens_psf_gaussian(ctx, rng):
    """Lens blur of the complex signal: a Gaussian point spread (sigma = 0.5-1.2 px) mixes the
    returns of neighbouring surfaces at depth edges (flying pixels). Godbaz, Cree, Dorrington
    2013 (above), sec. 4.1 (the PSF as the cause of mixed pixels); J. Mure-Dubois and H. Hugli,
    "Real-time scattering compensation for time-of-flight camera", ICVS 2007, sec. 2 (the
    complex-domain convolution model)."""
    sg = rng.uniform(0.5, 1.2)

    def sig(c, ns):
        return _oversampled_signal(c, ns, 3, blur_px=sg)

    return Plan(signal=sig), sg, "PSF sigma, px", {"psf_sigma_px": sg}


def mp_specular_floor(ctx, rng):
    """A second path via a glossy floor (specular reflectance G = 0.15-0.5): source -> floor ->
    point -> camera, length r + |P - C'| (C' the camera mirrored in the floor), irradiance
    G cos / |P - C'|^2 at the point; the pixel sees Z = Z_direct + Z_second. D. Jimenez, D.
    Pizarro, M. Mazo, S. Palazuelos, "Modeling and correction of multipath interference in time of
    flight cameras", Image and Vision Computing 32(1), 2014, sec. 3 (specular and diffuse
    multipath); J. P. Godbaz, M. J. Cree, A. A. Dorrington, "Closed-form inverses for the mixed
    pixel/multipath interference problem in AMCW lidar", Proc. SPIE 8296, 2012 (two-return model)."""
    gam = rng.uniform(0.15, 0.5)
    fy = ctx.spec.floor_y
    g = ctx.geom
    p = g["points"]
    cm = np.array([0.0, 2 * fy, 0.0])
    v = cm - p
    l2 = np.linalg.norm(v, axis=-1)
    cos2 = np.clip(np.sum(g["normals"] * v, axis=-1) / l2, 0, 1)
    above = p[..., 1] > fy + 1e-3
    e2 = np.where(above, ctx.k_act * g["rho"] * gam * cos2 / l2**2, 0.0)
    ph2 = 2 * np.pi * F_MOD * (g["r"] + l2) / C0

    def sig(c, ns):
        s = base_signal(c, ns)
        return {n: s[n] + (e2 if n == 0 else e2 * np.exp(1j * n * ph2)) for n in ns}

    ratio = float(np.median(e2[above] / ctx.e_act[above]))
    return (
        Plan(signal=sig),
        gam,
        "specular reflectance of the floor",
        {"median_second_to_direct": ratio},
    )


def mp_diffuse_interreflection(ctx, rng):
    """Diffuse two-bounce multipath: every visible surface patch Q lit by the source re-emits
    (Lambertian) towards the point P: dE_P ~ rho_P rho_Q cos_Q,in / r_Q^2 cos_Q,out cos_P,in
    dA_Q / (pi |P-Q|^2), path r_Q + |Q-P| + r_P; patches = 10 x 10-pixel blocks of the visible
    scene (no occlusion test), strength scaled by k = 0.8-2. S. Fuchs, "Multipath interference
    compensation in time-of-flight camera images", ICPR 2010, sec. 2, eq. (3)."""
    k = rng.uniform(0.8, 2.0)
    g = ctx.geom
    b = 10
    hb, wb = ctx.h // b, ctx.w // b
    sl = (slice(b // 2, hb * b, b), slice(b // 2, wb * b, b))
    q = g["points"][sl].reshape(-1, 3)
    nq = g["normals"][sl].reshape(-1, 3)
    rq = g["r"][sl].ravel()
    rhoq = g["rho"][sl].ravel()
    cq_in = g["cos_inc"][sl].ravel()
    fx = (ctx.w / 2) / math.tan(math.radians(HFOV_DEG) / 2)
    area = (b / fx) ** 2 * rq**2 / cq_in  # patch area seen by b x b pixels
    p = g["points"].reshape(-1, 3)
    npn = g["normals"].reshape(-1, 3)
    e2 = np.zeros(len(p))
    z2 = np.zeros(len(p), complex)
    for j in range(len(q)):
        v = p - q[j]
        dist = np.linalg.norm(v, axis=1) + 1e-9
        u = v / dist[:, None]
        cq = np.clip(u @ nq[j], 0, 1)
        cp = np.clip(-np.sum(u * npn, axis=1), 0, 1)
        e = (
            rhoq[j]
            * cq_in[j]
            / rq[j] ** 2
            * cq
            * cp
            * area[j]
            / (np.pi * np.maximum(dist, 0.1) ** 2)
        )
        e2 += e
        z2 += e * np.exp(1j * 2 * np.pi * F_MOD * (rq[j] + dist + g["r"].ravel()) / C0)
    rho = g["rho"].ravel()
    e2 = (k * ctx.k_act * rho * e2).reshape(ctx.h, ctx.w)
    z2 = (k * ctx.k_act * rho * z2).reshape(ctx.h, ctx.w)
    # only the fundamental's phase is modelled for the indirect light (a sum of paths)
    ph = np.angle(z2)
    mag = np.abs(z2)

    def sig(c, ns):
        s = base_signal(c, ns)
        return {n: s[n] + (e2 if n == 0 else mag * np.exp(1j * n * ph)) for n in ns}

    ratio = float(np.median(e2 / ctx.e_act))
    return Plan(signal=sig), k, "x Fuchs' two-bounce light", {"median_indirect_to_direct": ratio}


def nf_gaussian_phase_jitter(ctx, rng):
    """Clock jitter: the demodulation's timing error is Gaussian per pixel and frame with sigma_t
    (sigma_phi = 2 pi f sigma_t), the same for bright and dark pixels; sigma_phi = 2.5-5 x the
    per-frame phase noise at the median pixel (typically 150-600 ps). R. Lange,
    PhD thesis 2000, sec. 4.2 (noise sources of the phase measurement); B. Buttgen, T. Oggier, M.
    Lehmann, R. Kaufmann, F. Lustenberger, "CCD/CMOS lock-in pixel for range imaging: challenges,
    limitations and state-of-the-art", 1st Range Imaging Research Day, ETH Zurich 2005, sec. 3."""
    sp = rng.uniform(2.5, 5.0) * float(np.median(noise_rad(ctx))) * math.sqrt(ctx.t)
    st = sp / (2 * np.pi * F_MOD)
    ph = sp * rng.standard_normal((ctx.t, 1, ctx.h, ctx.w))
    return (
        Plan(phase=ph, temporal=True),
        st * 1e12,
        "ps rms timing jitter",
        {"phase_rms_rad": sp, "depth_rms_m": sp * M_PER_RAD},
    )


def nf_tap_timing_jitter(ctx, rng):
    """Sampling-phase jitter: each of the 4 samples has its own random phase-step error
    theta_k + e_k, e_k ~ N(0, s), per pixel and frame (a phase-shifting estimate with random
    phase-shift errors; the phase error's rms is s sqrt(3/8)); s set for 2.5-5 x the per-frame
    phase noise at the median pixel. J. Brophy, "Effect of intensity error correlation on
    the computed phase of phase-shifting interferometry", JOSA A 7(4), 1990; K. Creath,
    "Phase-measurement interferometry techniques", Progress in Optics 26, 1988, sec. 5."""
    s = rng.uniform(2.5, 5.0) * float(np.median(noise_rad(ctx))) * math.sqrt(ctx.t)
    s /= math.sqrt(3 / 8)
    th = s * rng.standard_normal((ctx.t, N_PHASES, ctx.h, ctx.w))
    return Plan(theta=th, temporal=True), s, "rad rms per sample", {"theta_rms_rad": s}


DEV_FORMS: dict[str, dict[str, Callable]] = {
    "saturation": {"adc_clip": sat_adc_clip, "well_prnu": sat_well_prnu, "log_knee": sat_log_knee},
    "fpn_pattern": {
        "column_adc_offsets": fpn_column_adc_offsets,
        "row_offsets": fpn_row_offsets,
        "dsnu_tap_map": fpn_dsnu_tap_map,
        "column_1f_phase": fpn_column_1f_phase,
        "kinect_p0": fpn_kinect_p0,
    },
    "amplitude_bias": {
        "lindner_kolb_log": ab_lindner_kolb_log,
        "weakest_pixels": ab_weakest_pixels,
        "exp_decay": ab_exp_decay,
    },
    "cyclic_error": {"square_wave": ce_square_wave, "triangular_correlation": ce_triangular},
    "pixel_gain": {"prnu_white": pg_prnu_white, "column_gain": pg_column_gain},
    "impulsive_pixels": {"hot_pixels": imp_hot_pixels, "dark_rts": imp_dark_rts},
    "vignetting": {"cos4_lens": vig_cos4, "led_lambertian": vig_led_lambertian},
    "temporal_drift": {"warmup_exp": td_warmup_exp, "thermal_gradient": td_thermal_gradient},
    "flying_pixels": {
        "pixel_footprint_mix": fp_pixel_footprint_mix,
        "lens_psf_gaussian": fp_lens_psf_gaussian,
    },
    "multipath": {
        "specular_floor": mp_specular_floor,
        "diffuse_interreflection": mp_diffuse_interreflection,
    },
    "noise_floor": {
        "gaussian_phase_jitter": nf_gaussian_phase_jitter,
        "tap_timing_jitter": nf_tap_timing_jitter,
    },
}


# ----------------------------------------------------------------------------------------------
# a recording
# ----------------------------------------------------------------------------------------------


def _wrap_m(d):
    return np.mod(d + RANGE_M / 2, RANGE_M) - RANGE_M / 2


def _stats(ctx, plan, clean_nl, eff_nl, eff_noisy):
    """The effect's size against the camera noise (see the module docstring)."""
    t = ctx.t
    _, d0, a0 = clean_nl
    raw1, d1, a1 = eff_nl
    _, dn, an = eff_noisy
    both = np.isfinite(d0) & np.isfinite(d1)
    diff = np.where(both, _wrap_m(d1 - d0), 0.0)
    arel = np.where(a0 > 0, a1 / np.maximum(a0, 1e-9) - 1, 0.0)
    res = np.where(np.isfinite(dn) & np.isfinite(d1), _wrap_m(dn - d1), np.nan)
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        sig_pix = np.nanstd(res, axis=0)
        ares = np.nanstd((an - a1) / np.maximum(a0, 1e-9), axis=0)
    affected = (
        (np.abs(diff) > 1e-5).any(0)
        | (np.abs(arel) > 1e-4).any(0)
        | (np.isfinite(d0) != np.isfinite(d1)).any(0)
    )
    frac = float(affected.mean())
    out = {
        "affected_fraction": frac,
        "noise_per_frame_m": float(np.nanmedian(sig_pix)),
        "noise_temporal_mean_m": float(np.nanmedian(sig_pix) / math.sqrt(t)),
        "rms_depth_change_m": float(np.sqrt(np.mean(diff[:, both.all(0)] ** 2)))
        if both.all(0).any()
        else 0.0,
        "rms_amplitude_change_rel": float(np.sqrt(np.mean(arel**2))),
        "newly_invalid_fraction": float((np.isfinite(d0) & ~np.isfinite(d1)).mean()),
    }
    if frac > 0:
        da = diff[:, affected]
        sp = np.nanmedian(sig_pix[affected])
        ap = np.nanmedian(ares[affected])
        out["rms_depth_change_affected_m"] = float(np.sqrt(np.mean(da**2)))
        out["rms_amplitude_change_affected_rel"] = float(np.sqrt(np.mean(arel[:, affected] ** 2)))
        ref_d = sp if plan.temporal else sp / math.sqrt(t)
        ref_a = ap if plan.temporal else ap / math.sqrt(t)
        out["noise_reference"] = "per-frame" if plan.temporal else "temporal-mean"
        out["visibility_depth"] = float(out["rms_depth_change_affected_m"] / max(ref_d, 1e-9))
        out["visibility_amplitude"] = float(
            out["rms_amplitude_change_affected_rel"] / max(ref_a, 1e-9)
        )
        out["visibility"] = max(out["visibility_depth"], out["visibility_amplitude"])
    else:
        out["visibility"] = 0.0
    out["clipped_sample_fraction"] = float(np.mean(raw1 >= ADC_MAX)) if raw1 is not None else 0.0
    return out


def generate_with(
    forms, scenes, family, form, seed, size=(120, 160, 24), part="dev", source=SOURCE
):
    """A recording with ``family``/``form`` planted (family "none": a null), for any form table."""
    h, w, t = size
    ss = np.random.SeedSequence([int(seed), PART_CODES[part]])
    r_scene, r_eff, r_noise = (np.random.default_rng(s) for s in ss.spawn(3))
    names = sorted(scenes)
    scene_name = names[int(r_scene.integers(0, len(names)))]
    spec = scenes[scene_name](r_scene)
    ctx = make_ctx(spec, h, w, t, r_scene)
    if family == "none":
        plan, mag, unit, size_d, doc = Plan(), 0.0, "", {}, "no effect"
    else:
        builder = forms[family][form]
        plan, mag, unit, size_d = builder(ctx, r_eff)
        doc = " ".join((builder.__doc__ or "").split())
    eff_noisy = render(ctx, plan, r_noise)
    raw, depth, amp = eff_noisy
    truth = {
        "family": family,
        "form": form,
        "magnitude": float(mag),
        "magnitude_unit": unit,
        "size": {
            k: (float(v) if isinstance(v, (int, float, np.floating)) else v)
            for k, v in size_d.items()
        },
        "scene": scene_name,
        "seed": int(seed),
        "part": part,
        "citation": doc,
    }
    if family != "none":
        clean_nl = render(ctx, Plan(), None)
        eff_nl = render(ctx, plan, None)
        truth["stats"] = _stats(ctx, plan, clean_nl, eff_nl, eff_noisy)
    integ = BASE_INTEGRATION_US * plan.exposure
    return {
        "depth": depth.astype(np.float32),
        "amplitude": amp.astype(np.float32),
        "raw": raw.astype(np.float32),
        "meta": {
            "modulation_frequency_hz": F_MOD,
            "integration_time_us": float(integ),
            "n_phases": N_PHASES,
            "amplitude_unit": "DN",
            "source": source,
        },
        "scene_depth": ctx.geom["r"].astype(np.float64),
        "reflectance": ctx.geom["rho"].astype(np.float64),
        "truth": truth,
    }


def generate(family, form, seed, size=(120, 160, 24)):
    """A dev recording: ``family`` in DEV_FORMS (or "none" with form "null"), deterministic per
    seed. Returns the dict described in the module docstring."""
    return generate_with(DEV_FORMS, DEV_SCENES, family, form, seed, size, "dev")


def cases(forms, per_form, nulls, seed0):
    """(family, form, seed) for every form x per_form recordings, then the nulls."""
    out = []
    s = seed0
    for fam in forms:
        for form in forms[fam]:
            for _ in range(per_form):
                out.append((fam, form, s))
                s += 1
    for _ in range(nulls):
        out.append(("none", "null", s))
        s += 1
    return out
