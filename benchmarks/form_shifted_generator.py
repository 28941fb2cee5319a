"""A form-shifted ToF recording generator for the diagnosis benchmark (NumPy only).

Written without reading the diagnosis (``tof_fpn_torch.diagnosis``) and apart from the simulator:
every effect has two functional forms (``"A"``, ``"B"``) that differ from each other, from the
diagnosis catalogue's stated forms and from ``concealed_generator.py``'s, and the scenes are other
models than the catalogue's synthetic / planar / ramp scenes.

Camera (pinhole, 70 deg horizontal field; x right, y down, z forward; depth = radial distance):
    electrons of sample n:  q_n = amb + S (1 + c w(phi + 2 pi n / N)) + o_n(x),
    S = k_sig rho / d^2,  amb = bg rho,  phi = 4 pi f d / c_air,  w = cos (unless cyclic A),
    o_n(x) = [a1 cos(2 pi x / 3 + t1) + a2 cos(pi x)] cos(2 pi n / N - psi)  (base column FPN),
    exact Poisson shot noise, Gaussian read noise, gain to DN, rounding, 16-bit ADC, decoding by
    the first DFT bin (depth in [0, R), R = c_air / (2 f); amplitude in DN).

Scene models (:func:`scene_model`; depth within 0.35-6.6 m, reflectance in [0.05, 0.95]):
    corner    room corner: floor, back wall, one side wall and a cabinet against the back wall
              seen by a pitched camera; checker floor, striped back wall, smooth-noise side wall
    steps     boxes (steps) standing on a floor in front of a checker back wall, noise texture
    solids    spheres and upright cylinders on a floor in front of a wall, striped solids
    polygons  piecewise-planar random polygons (Voronoi cells, each a tilted plane) with a
              checker, stripe or noise texture per cell

Effects and forms (``magnitude`` in the unit given; ``truth["effect_size"]`` in ``effect_size_unit``):
    amplitude_bias    A: delay b exp(-A / A0), A0 = 20th percentile of the active amplitude;
                      B: delay b clip((ln A_hi - ln A) / (ln A_hi - ln A_lo), 0, 1), a ramp in
                      log amplitude (A_lo, A_hi = 5th, 60th percentiles). magnitude b (mm: the
                      bias as A -> 0 in A, of every pixel below A_lo in B); effect size: RMS depth error (mm, affected pixels)
    cyclic_error      A: an over-driven LED: the light a cosine clipped at +-k, through a
                      first-order low-pass (0.3 rad), reference a square wave; B: a direct
                      depth error with harmonics 2 and 3 of the range (periods R/2, R/3), random
                      phases and ratio. magnitude: peak-to-peak depth error over the range (mm)
    fpn_pattern       A: per-column delays with a 1/f power spectrum (pink); B: block offsets, 8
                      column ADC groups times top / bottom read-out halves. magnitude: RMS (mm)
    readout_pattern   (named ``fpn_pattern``) a fixed complex offset Z(x, y) added to the samples,
                      o_n = |Z| cos(2 pi n / N - arg Z), the same in every frame, not scaling with
                      the light; A: column part + i.i.d. pixel part (equal power); B: smooth 2-D
                      blobs + pixel part (equal power). magnitude: RMS |Z| (e-)
    pixel_gain        A: smooth blotches (white noise smoothed over ~5 px), gain 1 + g, RMS g =
                      magnitude; B: weak rows and pixel clusters at gain 1 - magnitude (two levels)
    impulsive_pixels  A: salt: fixed hot pixels that read their own constant code vector in a
                      random 25 % of the frames; B: bursts: short line segments (4-24 px) in single
                      frames offset by one random code vector. magnitude: share of frame-pixels
    saturation        A: ambient raised 6x in every sample and a hard full-well clip;
                      B: a soft knee, q -> K + (q - K) / (1 + (q - K) / (0.5 K)) above the knee K.
                      magnitude: share of pixels whose brightest (noise-free) sample passes the
                      well / knee (the brightest: high reflectance, near)
    flying_pixels     A: depth-edge pixels (a 4-neighbour > 0.15 m away) mix their samples with
                      that neighbour's at a random share u ~ U(0, 1); magnitude: share of edge
                      pixels mixed. B: a box footprint 1 + m px wide offset by a sub-pixel shift
                      (up to m / 4 px), area fractions of the 3 x 3 neighbourhood; magnitude m
                      (px)
    multipath         A: a specular second path off the floor plane (mirror image of the camera),
                      both ways, strength magnitude * (d / |P - C'|)^2 of the direct light;
                      magnitude: specular share. B: a two-bounce path from one wall patch
                      (12 x 12 px) relaying its light with 1 / r^2 (r >= 0.25 m); magnitude:
                      median relayed / direct active light
    noise_floor       A: heavy-tailed phase jitter (Student t, 3 degrees of freedom, scaled to
                      the sd given), not falling with amplitude; B: Gaussian phase jitter with a
                      per-column sd (log-normal column profile). magnitude: RMS sd (mm)
    phase_wrapping    A: the scene stretched (all depths scaled) so that a share lies beyond R at
                      20 MHz; B: a far room: the farthest share of the scene pushed to R + 0.2 m
                      and beyond ("a doorway"). magnitude: share of the scene beyond R. The scene
                      returned (``out["scene_depth"]``) is the one recorded.
    temporal_drift    A: a sinusoidal delay oscillation (1.5 periods over the recording);
                      B: a step of the delay at a random frame in the middle third.
                      magnitude: peak-to-peak delay (mm)
    vignetting        A: an elliptical Gaussian fall-off about an off-centre, rotated axis;
                      B: a mechanical vignette: a dark corner sector with a smooth radial step.
                      magnitude: largest light loss (fraction)

``truth["snr"]`` states how visible the effect is, from noise-free samples with and without it
(decoded alike): depth effects: RMS over the affected pixels (|change| >= 10 % of its 99th
percentile) of the temporal-mean depth change over the per-pixel temporal-mean depth sd
(sd / sqrt(T), from the null's expected samples); amplitude effects (pixel_gain, vignetting):
the same with the relative amplitude; temporal_drift: the RMS over frames of the change about its
mean, over the same sd; noise_floor: the added variance over the standard error of a pixel's
variance over T frames (sigma0^2 sqrt(2 / (T - 1))), RMS over pixels. Share effects
(impulsive_pixels, saturation, phase_wrapping, flying_pixels A) state shares instead.
"""

from __future__ import annotations

import math

import numpy as np

C_AIR = 299792458.0 / 1.000293
FIELD_OF_VIEW_DEG = 70.0
SCENES = ("corner", "steps", "solids", "polygons")
FORMS = ("A", "B")
EFFECTS = (
    "amplitude_bias",
    "cyclic_error",
    "fpn_pattern",
    "readout_pattern",
    "pixel_gain",
    "impulsive_pixels",
    "saturation",
    "flying_pixels",
    "multipath",
    "noise_floor",
    "phase_wrapping",
    "temporal_drift",
    "vignetting",
)
#: the catalogue name the diagnosis should give each planted effect
EXPECTED = {e: ("fpn_pattern" if e == "readout_pattern" else e) for e in EFFECTS}
#: which statistic ``truth["snr"]`` is (see the module docstring)
SNR_KIND = {
    "amplitude_bias": "depth",
    "cyclic_error": "depth",
    "fpn_pattern": "depth",
    "readout_pattern": "depth",
    "pixel_gain": "amplitude",
    "flying_pixels": "depth",
    "multipath": "depth",
    "temporal_drift": "drift",
    "noise_floor": "noise",
    "vignetting": "amplitude",
}
EDGE_STEP_M = 0.15  # depth step that makes a flying-pixel edge (m)
SALT_FIRE = 0.25  # probability a hot pixel fires in a frame
SAT_AMBIENT = 6.0  # ambient factor of saturation A
KNEE_SOFT = 0.5  # saturation B: asymptote K (1 + KNEE_SOFT)
PATCH_PX = 12  # multipath B: side of the relaying patch
RELAY_MIN_M = 0.25  # multipath B: nearest relay distance


# ----------------------------------------------------------------------------- scene models


def rays(h: int, w: int) -> np.ndarray:
    """Unit ray directions (H, W, 3) of the pinhole camera."""
    fx = (w / 2) / math.tan(math.radians(FIELD_OF_VIEW_DEG / 2))
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    r = np.stack([(xx - (w - 1) / 2) / fx, (yy - (h - 1) / 2) / fx, np.ones((h, w))], -1)
    return r / np.linalg.norm(r, axis=-1, keepdims=True)


def _pitch(r: np.ndarray, angle: float) -> np.ndarray:
    """Rays of a camera pitched down by ``angle`` (rad), in a world frame (y down)."""
    c, s = math.cos(angle), math.sin(angle)
    y = c * r[..., 1] + s * r[..., 2]
    z = -s * r[..., 1] + c * r[..., 2]
    return np.stack([r[..., 0], y, z], -1)


def _plane_hit(r: np.ndarray, normal, offset: float) -> np.ndarray:
    """Distance along each ray to the plane n . X = offset (inf where behind / parallel)."""
    den = r @ np.asarray(normal, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = offset / den
    return np.where((den * np.sign(offset) > 1e-9) & (t > 0), t, np.inf)


def _smooth_noise(rng, shape, scale_px: float) -> np.ndarray:
    """Zero-mean, unit-sd Gaussian-smoothed white noise (FFT filter, periodic)."""
    h, w = shape
    ky = np.fft.fftfreq(h)[:, None]
    kx = np.fft.fftfreq(w)[None, :]
    filt = np.exp(-2 * (np.pi * scale_px) ** 2 * (kx**2 + ky**2))
    x = np.real(np.fft.ifft2(np.fft.fft2(rng.standard_normal(shape)) * filt))
    return (x - x.mean()) / max(x.std(), 1e-12)


def _checker(u, v, period: float) -> np.ndarray:
    return (np.floor(u / period) + np.floor(v / period)) % 2


def _finish(depth, rho, rng, base=0.0) -> tuple[np.ndarray, np.ndarray]:
    rho = rho * (1 + 0.12 * _smooth_noise(rng, depth.shape, 1.5)) + base
    return depth, np.clip(rho, 0.05, 0.95)


def _room(rng, h, w, pitch_deg):
    """Pitched rays, floor height and distance of the back wall (shared by three scenes)."""
    r = _pitch(rays(h, w), math.radians(rng.uniform(*pitch_deg)))
    return r, rng.uniform(0.9, 1.3), rng.uniform(3.2, 4.4)


def _corner(rng, h, w):
    r, hf, zb = _room(rng, h, w, (5, 15))
    side = rng.choice([-1.0, 1.0]) * rng.uniform(1.1, 2.0)
    x0 = rng.uniform(-0.9, 0.2)  # a cabinet against the back wall (depth edges)
    cabinet = (x0, hf - rng.uniform(0.6, 1.2), zb - rng.uniform(0.4, 0.7)), (x0 + 0.7, hf, zb)
    hits = [_plane_hit(r, (0, 1, 0), hf), _plane_hit(r, (0, 0, 1), zb)]
    hits = np.stack([*hits, _plane_hit(r, (1, 0, 0), side), _box_hit(r, *cabinet)])
    which = hits.argmin(0)
    d = hits.min(0)
    p = r * d[..., None]
    floor = 0.25 + 0.45 * _checker(p[..., 0], p[..., 2], rng.uniform(0.3, 0.6))
    wall = 0.3 + 0.4 * (np.sin(2 * np.pi * p[..., 0] / rng.uniform(0.2, 0.5)) > 0)
    side_t = 0.5 + 0.15 * _smooth_noise(rng, (h, w), 4.0)
    rho = np.choose(which, [floor, wall, side_t, np.full((h, w), rng.uniform(0.2, 0.8))])
    return (*_finish(d, rho, rng), {"floor_normal": _floor_normal(r), "floor_m": hf})


def _floor_normal(r_pitched: np.ndarray) -> list[float]:
    """The floor normal (world y) in camera coordinates, recovered from the pitched rays."""
    cam = rays(*r_pitched.shape[:2])
    # the pitch is a rotation about x: camera y-axis in world = (0, c, -s)
    m, *_ = np.linalg.lstsq(cam.reshape(-1, 3), r_pitched.reshape(-1, 3), rcond=None)
    return [float(v) for v in m[:, 1]]


def _box_hit(r, lo, hi) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = np.asarray(lo) / r
        t2 = np.asarray(hi) / r
    tn = np.nanmax(np.minimum(t1, t2), axis=-1)
    tf = np.nanmin(np.maximum(t1, t2), axis=-1)
    return np.where((tf >= tn) & (tn > 0), tn, np.inf)


def _steps(rng, h, w):
    r, hf, zb = _room(rng, h, w, (8, 18))
    hits = [_plane_hit(r, (0, 1, 0), hf), _plane_hit(r, (0, 0, 1), zb)]
    albedo = [None, None]
    for _ in range(rng.integers(3, 6)):
        x0, z0 = rng.uniform(-1.4, 1.0), rng.uniform(1.4, zb - 0.6)
        lo = (x0, hf - rng.uniform(0.15, 0.8), z0)
        hi = (x0 + rng.uniform(0.3, 0.8), hf, z0 + rng.uniform(0.3, 0.6))
        hits.append(_box_hit(r, lo, hi))
        albedo.append(rng.uniform(0.15, 0.85))
    hits = np.stack(hits)
    which, d = hits.argmin(0), hits.min(0)
    p = r * d[..., None]
    rho = np.where(which == 0, 0.35 + 0.1 * _smooth_noise(rng, (h, w), 3.0), 0.0)
    rho = np.where(which == 1, 0.3 + 0.4 * _checker(p[..., 0], p[..., 1], 0.4), rho)
    for k in range(2, len(albedo)):
        rho = np.where(which == k, albedo[k], rho)
    return (*_finish(d, rho, rng), {"floor_normal": _floor_normal(r), "floor_m": hf})


def _sphere_hit(r, c, rad):
    b = r @ np.asarray(c)
    disc = b**2 - (np.dot(c, c) - rad**2)
    t = b - np.sqrt(np.clip(disc, 0, None))
    return np.where((disc > 0) & (t > 0), t, np.inf)


def _cylinder_hit(r, x0, z0, rad, y_top, y_floor):
    a = r[..., 0] ** 2 + r[..., 2] ** 2
    b = r[..., 0] * x0 + r[..., 2] * z0
    disc = b**2 - a * (x0**2 + z0**2 - rad**2)
    t = (b - np.sqrt(np.clip(disc, 0, None))) / a
    y = t * r[..., 1]
    return np.where((disc > 0) & (t > 0) & (y > y_top) & (y < y_floor), t, np.inf)


def _solids(rng, h, w):
    r, hf, zb = _room(rng, h, w, (3, 10))
    hits = [_plane_hit(r, (0, 1, 0), hf), _plane_hit(r, (0, 0, 1), zb)]
    for _ in range(rng.integers(2, 4)):
        rad = rng.uniform(0.2, 0.45)
        c = (rng.uniform(-1.2, 1.2), rng.uniform(-0.4, hf - rad), rng.uniform(1.4, zb - 0.6))
        hits.append(_sphere_hit(r, c, rad))
    for _ in range(rng.integers(1, 3)):
        x0, z0 = rng.uniform(-1.3, 1.3), rng.uniform(1.2, zb - 0.5)
        hits.append(_cylinder_hit(r, x0, z0, rng.uniform(0.12, 0.3), rng.uniform(-1.0, 0.3), hf))
    hits = np.stack(hits)
    which, d = hits.argmin(0), hits.min(0)
    p = r * d[..., None]
    stripes = 0.2 + 0.6 * (np.sin(2 * np.pi * p[..., 1] / rng.uniform(0.08, 0.2)) > 0)
    rho = np.where(which >= 2, stripes, 0.45 + 0.12 * _smooth_noise(rng, (h, w), 5.0))
    rho = np.where(which == 0, 0.3 + 0.3 * _checker(p[..., 0], p[..., 2], 0.5), rho)
    return (*_finish(d, rho, rng), {"floor_normal": _floor_normal(r), "floor_m": hf})


def _polygons(rng, h, w):
    r = rays(h, w)
    k = int(rng.integers(7, 13))
    seeds = np.stack([rng.uniform(0, h, k), rng.uniform(0, w, k)], 1)
    yy, xx = np.mgrid[0:h, 0:w]
    dist = (yy[..., None] - seeds[:, 0]) ** 2 + (xx[..., None] - seeds[:, 1]) ** 2
    cell = dist.argmin(-1)
    d = np.zeros((h, w))
    rho = np.zeros((h, w))
    noise = _smooth_noise(rng, (h, w), 2.0)
    for i in range(k):
        tilt, az = math.radians(rng.uniform(0, 45)), rng.uniform(0, 2 * np.pi)
        n = np.array([math.sin(tilt) * math.cos(az), math.sin(tilt) * math.sin(az), math.cos(tilt)])
        sel = cell == i
        ray_c = r[int(seeds[i, 0]), int(seeds[i, 1])]
        off = rng.uniform(1.0, 4.5) * float(ray_c @ n)
        d[sel] = np.clip(off / np.clip(r[sel] @ n, 0.05, None), 0.5, 6.2)
        base = rng.uniform(0.15, 0.75)
        tex = [
            _checker(yy, xx, rng.uniform(3, 9))[sel],
            (np.sin(xx * rng.uniform(0.3, 1.2) + yy * rng.uniform(-0.5, 0.5)) > 0)[sel],
            0.5 + 0.5 * np.tanh(noise[sel]),
        ][int(rng.integers(0, 3))]
        rho[sel] = base * (0.6 + 0.6 * tex)
    return (*_finish(d, rho, rng), {"floor_normal": [0.0, 1.0, 0.0], "floor_m": 1.2})


def scene_model(kind: str, h: int, w: int, seed: int) -> tuple[np.ndarray, np.ndarray, dict]:
    """``(depth, reflectance, info)``: (H, W) float64 radial depth (m) and reflectance of one of
    :data:`SCENES`; ``info`` holds the floor plane in camera coordinates (normal, distance)."""
    if kind not in SCENES:
        raise ValueError(f"scene must be one of {SCENES}, got {kind!r}")
    rng = np.random.default_rng([seed, 17])
    return {"corner": _corner, "steps": _steps, "solids": _solids, "polygons": _polygons}[kind](
        rng, h, w
    )


# ----------------------------------------------------------------------------- camera


class Camera:
    """The base camera (the same in every recording); keyword overrides in :func:`generate`."""

    def __init__(
        self,
        frequency: float = 20e6,
        n_phases: int = 4,
        k_sig: float = 3.0e4,
        bg: float = 400.0,
        contrast: float = 0.5,
        gain: float = 25.0,
        read_e: float = 10.0,
        fpn: tuple[float, float] = (20.0, 15.0),
        psi: float = 0.8,
    ):
        self.frequency, self.n_phases, self.k_sig, self.bg = frequency, n_phases, k_sig, bg
        self.contrast, self.gain, self.read_e, self.fpn, self.psi = contrast, gain, read_e, fpn, psi

    @property
    def range_m(self) -> float:
        return C_AIR / (2 * self.frequency)

    @property
    def thetas(self) -> np.ndarray:
        return 2 * np.pi * np.arange(self.n_phases) / self.n_phases


def decode(q: np.ndarray, frequency: float) -> tuple[np.ndarray, np.ndarray]:
    """First-DFT-bin decoding of (T, N, H, W) samples: depth in [0, R) (m) and amplitude (the
    samples' unit)."""
    n = q.shape[1]
    z = np.tensordot(np.exp(-2j * np.pi * np.arange(n) / n), q, axes=(0, 1))
    depth = np.mod(np.angle(z), 2 * np.pi) * C_AIR / (4 * np.pi * frequency)
    return depth, 2.0 / n * np.abs(z)


# ----------------------------------------------------------------------------- effect pieces


LED_TAU = 0.3  # cyclic A: the LED's first-order time constant (radians of the period)


def _led_harmonics(clip: float, k_max: int = 61) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cyclic A: odd harmonics k, amplitudes a_k (a_1 = 1) and phases (theta_1 = 0) of the
    correlation of an over-driven LED's light -- a cosine clipped at +-``clip`` (1: not clipped)
    through a first-order low-pass (LED_TAU) -- with a square-wave reference."""
    t = np.arange(4096) * 2 * np.pi / 4096
    k = np.arange(1, k_max + 1, 2)
    light = np.fft.rfft(np.clip(np.cos(t), -clip, clip))[k] / (1 + 1j * k * LED_TAU)
    ref = (-1.0) ** ((k - 1) // 2) / k  # square wave sign(cos t), up to 4 / pi
    c = light * ref
    c = c * np.exp(-1j * k * np.angle(c[0]))  # time shift: the fundamental at phase 0
    return k.astype(np.float64), np.abs(c) / abs(c[0]), np.angle(c)


def _led_wave(arg: np.ndarray, clip: float) -> np.ndarray:
    k, a, th = _led_harmonics(clip)
    out = np.zeros_like(arg)
    for kk, aa, tt in zip(k, a, th, strict=True):
        if aa > 1e-6:
            out += aa * np.cos(kk * arg + tt)
    return out


def _led_peak_to_peak_mm(clip: float, cam: Camera) -> float:
    phi = np.linspace(0, 2 * np.pi, 512, endpoint=False)
    arg = phi[None, None, :, None] + cam.thetas[None, :, None, None]  # (1, N, 512, 1)
    d, _ = decode(_led_wave(arg, clip), cam.frequency)
    err = np.angle(np.exp(1j * (d[0, :, 0] * 4 * np.pi * cam.frequency / C_AIR - phi)))
    return float(np.ptp(err) * C_AIR / (4 * np.pi * cam.frequency) * 1e3)


def _led_clip(target_mm: float, cam: Camera) -> float:
    """The clip level (the least distortion) whose peak-to-peak error reaches ``target_mm``
    (bisection; the error falls as the clip level rises to 1)."""
    lo, hi = 1e-3, 1.0
    if _led_peak_to_peak_mm(lo, cam) <= target_mm:
        return lo
    for _ in range(40):
        mid = (lo + hi) / 2
        if _led_peak_to_peak_mm(mid, cam) > target_mm:
            lo = mid
        else:
            hi = mid
    return lo


def _pink(rng, n: int) -> np.ndarray:
    """Unit-RMS profile of length ``n`` with a 1/f power spectrum (no DC)."""
    k = np.fft.rfftfreq(n)
    amp = np.where(k > 0, 1 / np.sqrt(np.where(k > 0, k, 1)), 0.0)
    spec = amp * np.exp(2j * np.pi * rng.random(k.size))
    x = np.fft.irfft(spec, n)
    return (x - x.mean()) / x.std()


def _delay(ctx, effect, form, m, sig, rng, truth) -> np.ndarray:
    """Delay (m) of the effects that shift the phase: (T or 1, H, W)."""
    cam, (h, w), t = ctx["cam"], ctx["d"].shape, ctx["frames"]
    out = np.zeros((1, h, w))
    if effect == "amplitude_bias":
        a = cam.contrast * sig
        if form == "A":
            b = np.exp(-a / np.quantile(a, 0.2))
        else:
            lo, hi = np.log(np.quantile(a, 0.05)), np.log(np.quantile(a, 0.6))
            b = np.clip((hi - np.log(a)) / (hi - lo), 0, 1)
        out = out + m * 1e-3 * b[None]
    elif effect == "cyclic_error" and form == "B":
        r = cam.range_m
        ph2, ph3, ratio = (
            rng.uniform(0, 2 * np.pi),
            rng.uniform(0, 2 * np.pi),
            rng.uniform(0.4, 0.8),
        )
        f = lambda x: np.sin(4 * np.pi * x / r + ph2) + ratio * np.sin(6 * np.pi * x / r + ph3)  # noqa: E731
        pp = np.ptp(f(np.linspace(0, r, 4096, endpoint=False)))
        out = out + (m * 1e-3 / pp) * f(ctx["d"])[None]
        truth.update(harmonic_ratio=ratio, phases=[ph2, ph3])
    elif effect == "fpn_pattern" and form == "A":
        out = out + (m * 1e-3 * _pink(rng, w))[None, None, :]
    elif effect == "fpn_pattern":
        blocks = rng.standard_normal((2, -(-w // 8)))
        blocks = (blocks - blocks.mean()) / blocks.std()
        rows = (np.arange(h) >= h // 2).astype(int)
        out = out + m * 1e-3 * blocks[rows][:, np.arange(w) // 8][None]
    elif effect == "temporal_drift" and form == "A":
        ph = rng.uniform(0, 2 * np.pi)
        wave = np.sin(2 * np.pi * 1.5 * np.arange(t) / t + ph)
        out = out + (m * 1e-3 * wave / np.ptp(wave))[:, None, None]
    elif effect == "temporal_drift":
        step = int(rng.integers(t // 3, 2 * t // 3 + 1))
        out = out + (m * 1e-3 * (np.arange(t) >= step))[:, None, None]
        truth["step_frame"] = step
    return out


def _light(ctx, effect, form, m, rng, truth) -> np.ndarray:
    """Multiplicative light map (H, W) of pixel_gain and vignetting (1 elsewhere)."""
    h, w = ctx["d"].shape
    if effect == "pixel_gain" and form == "A":
        g = 1 + m * _smooth_noise(rng, (h, w), 5.0)
    elif effect == "pixel_gain":
        weak = np.zeros((h, w), bool)
        weak[rng.choice(h, 2, replace=False)] = True
        yy, xx = np.mgrid[0:h, 0:w]
        for _ in range(5):
            cy, cx, rad = rng.uniform(0, h), rng.uniform(0, w), rng.uniform(1.5, 3.0)
            weak |= (yy - cy) ** 2 + (xx - cx) ** 2 <= rad**2
        g = np.where(weak, 1 - m, 1.0)
        truth["weak_share"] = float(weak.mean())
    elif effect == "vignetting":
        g = _vignette(rng, h, w, form, m)
    else:
        return np.ones((h, w))
    return g


def _vignette(rng, h, w, form, m) -> np.ndarray:
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    if form == "A":  # elliptical Gaussian about an off-centre, rotated axis
        cy, cx = (h - 1) / 2 + rng.uniform(-0.1, 0.1) * h, (w - 1) / 2 + rng.uniform(-0.1, 0.1) * w
        ang, ratio = rng.uniform(0, np.pi), rng.uniform(1.3, 1.8)
        u = (xx - cx) * math.cos(ang) + (yy - cy) * math.sin(ang)
        v = -(xx - cx) * math.sin(ang) + (yy - cy) * math.cos(ang)
        quad = (u / ratio) ** 2 + v**2
        return np.exp(math.log(1 - m) * quad / quad.max())
    # B: a dark corner sector with a smooth radial step
    corner = rng.integers(0, 4)
    cy, cx = (h - 1) / 2, (w - 1) / 2
    dy, dx = (1 if corner // 2 else -1) * cy, (1 if corner % 2 else -1) * cx
    rc = math.hypot(dy, dx)
    r = np.hypot(yy - cy, xx - cx)
    cosang = ((yy - cy) * dy + (xx - cx) * dx) / (np.maximum(r, 1e-9) * rc)
    radial = 1 / (1 + np.exp(-(r - 0.72 * rc) / (0.05 * rc)))
    sector = 1 / (1 + np.exp(-(cosang - math.cos(math.radians(22))) / 0.01))
    return 1 - m * radial * sector


def _edge_neighbour(d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For every pixel the flat index of its 4-neighbour with the largest depth step, and
    whether that step exceeds :data:`EDGE_STEP_M`."""
    h, w = d.shape
    dp = np.pad(d, 1, mode="edge")
    idx = np.pad(np.arange(h * w).reshape(h, w), 1, mode="edge")
    cand = [(slice(0, -2), slice(1, -1)), (slice(2, None), slice(1, -1))]
    cand += [(slice(1, -1), slice(0, -2)), (slice(1, -1), slice(2, None))]
    steps = np.stack([np.abs(dp[c] - d) for c in cand])
    best = steps.argmax(0)
    nb = np.choose(best, [idx[c] for c in cand])
    return nb, steps.max(0) > EDGE_STEP_M, steps.max(0)


def _box_weights(m: float, shift: float) -> np.ndarray:
    """Overlap of a footprint [-(1+m)/2, (1+m)/2] + shift with pixels -1, 0, 1 (area fractions)."""
    lo, hi = shift - (1 + m) / 2, shift + (1 + m) / 2
    edges = [(-1.5, -0.5), (-0.5, 0.5), (0.5, 1.5)]
    wts = np.array([max(0.0, min(hi, b) - max(lo, a)) for a, b in edges])
    return wts / wts.sum()


def _flying(ctx, q, form, m, rng, truth) -> np.ndarray:
    h, w = ctx["d"].shape
    if form == "A":
        nb, edge, _ = _edge_neighbour(ctx["d"])
        mixed = edge & (rng.random((h, w)) < m)
        u = np.where(mixed, rng.random((h, w)), 0.0)
        qn = q.reshape(*q.shape[:2], -1)[..., nb.reshape(-1)].reshape(q.shape)
        truth.update(edge_share=float(edge.mean()), mixed_share=float(mixed.mean()))
        ctx["flying_mix"] = (mixed, nb, u)
        return (1 - u) * q + u * qn
    sy, sx = rng.uniform(-0.25, 0.25, 2) * m  # sub-pixel edge positions of the footprint
    wy, wx = _box_weights(m, sy), _box_weights(m, sx)
    qp = np.pad(q, ((0, 0), (0, 0), (1, 1), (1, 1)), mode="edge")
    out = np.zeros_like(q)
    for i in range(3):
        for j in range(3):
            out += wy[i] * wx[j] * qp[..., i : i + h, j : j + w]
    truth.update(shift_px=[float(sy), float(sx)], light_from_neighbours=float(1 - wy[1] * wx[1]))
    return out


def _points(ctx) -> np.ndarray:
    return ctx["d"][..., None] * rays(*ctx["d"].shape)


def _mirror(ctx, q, sig, m, truth) -> np.ndarray:
    """Multipath A: the floor mirrors the camera to C' = 2 c n; light reaches P (or returns)
    over the floor, path d + |P - C'|, both ways."""
    cam, d = ctx["cam"], ctx["d"]
    n = np.asarray(ctx["info"].get("floor_normal", [0.0, 1.0, 0.0]), dtype=np.float64)
    c = float(ctx["info"].get("floor_m", 1.2))
    p = _points(ctx)
    length = np.linalg.norm(p - 2 * c * n, axis=-1)
    ok = (p @ n < c - 0.05) & (length > d + 0.05)
    s = np.where(ok, 2 * m * sig * (d / length) ** 2, 0.0)
    ph = 2 * np.pi * cam.frequency * (d + length) / C_AIR
    arg = ph[None, None] + cam.thetas[None, :, None, None]
    truth["median_extra_path_m"] = float(np.median((length - d)[ok])) if ok.any() else 0.0
    truth["mirrored_share"] = float(ok.mean())
    return q + s[None, None] * (1 + cam.contrast * np.cos(arg))


def _patch_relay(ctx, q, sig, m, rng, truth) -> np.ndarray:
    """Multipath B: one PATCH_PX x PATCH_PX patch (upper half) relays its light to every point."""
    cam, d = ctx["cam"], ctx["d"]
    h, w = d.shape
    y0 = int(rng.integers(0, max(h // 2 - PATCH_PX, 1)))
    x0 = int(rng.integers(0, w - PATCH_PX))
    p = _points(ctx)
    src = (slice(y0, y0 + PATCH_PX), slice(x0, x0 + PATCH_PX))
    pq, dq = p[src].reshape(-1, 3), d[src].reshape(-1)
    sent = (sig * d**2)[src].reshape(-1)  # light each patch point reflects (any unit)
    r = np.maximum(np.linalg.norm(p.reshape(-1, 1, 3) - pq[None], axis=-1), RELAY_MIN_M)
    wt = sent[None] / r**2
    path = dq[None] + r + d.reshape(-1, 1)
    dc = wt.sum(1).reshape(h, w) * ctx["rho"]
    z = (wt * np.exp(2j * np.pi * cam.frequency * path / C_AIR)).sum(1).reshape(h, w) * ctx["rho"]
    outside = np.ones((h, w), bool)
    outside[src] = False
    scale = m / np.median((dc / sig)[outside])
    truth.update(patch_yx=[y0, x0], relay_share=m)
    zz = scale * z[None, None] * np.exp(1j * cam.thetas)[None, :, None, None]
    return q + scale * dc[None, None] + cam.contrast * np.real(zz)


def _readout(ctx, q, form, m, rng) -> np.ndarray:
    h, w = ctx["d"].shape
    cz = lambda *s: rng.standard_normal(s) + 1j * rng.standard_normal(s)  # noqa: E731
    pix = cz(h, w)
    if form == "A":
        smooth = np.broadcast_to(cz(w)[None, :], (h, w))
    else:
        yy, xx = np.mgrid[0:h, 0:w]
        smooth = np.zeros((h, w), complex)
        for _ in range(2):
            cy, cx, s = rng.uniform(0, h), rng.uniform(0, w), rng.uniform(15, 30)
            smooth += cz(1)[0] * np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / (2 * s**2))
    z = smooth / np.sqrt(np.mean(np.abs(smooth) ** 2)) + pix / np.sqrt(np.mean(np.abs(pix) ** 2))
    z = z * m / np.sqrt(np.mean(np.abs(z) ** 2))
    ctx["readout_map"] = z
    return q + np.real(z[None, None] * np.exp(-1j * ctx["cam"].thetas)[None, :, None, None])


# ----------------------------------------------------------------------------- the recording


def _expected(ctx, effect, form, m, truth, jitter=None) -> np.ndarray:
    """Noise-free electrons (T, N, H, W) before the full well (``jitter``: extra delay, m)."""
    cam, d, rho = ctx["cam"], ctx["d"], ctx["rho"]
    rng = np.random.default_rng([ctx["seed"], 1])  # the effect's structure: same in every call
    g = _light(ctx, effect, form, m, rng, truth)
    sig = cam.k_sig * rho / d**2 * g
    amb = cam.bg * rho * g * (SAT_AMBIENT if (effect, form) == ("saturation", "A") else 1.0)
    delay = _delay(ctx, effect, form, m, sig, rng, truth)
    if jitter is not None:
        delay = delay + jitter
    arg = (4 * np.pi * cam.frequency * (d + delay) / C_AIR)[:, None]
    arg = arg + cam.thetas[None, :, None, None]
    if (effect, form) == ("cyclic_error", "A"):
        clip = ctx.setdefault("led_clip", _led_clip(m, cam))
        truth.update(led_clip=clip, peak_to_peak_mm=_led_peak_to_peak_mm(clip, cam))
        wave = _led_wave(arg, clip)
    else:
        wave = np.cos(arg)
    q = amb[None, None] + sig[None, None] * (1 + cam.contrast * wave)
    q = np.broadcast_to(q, (ctx["frames"], *q.shape[1:])).copy()
    if effect == "flying_pixels":
        q = _flying(ctx, q, form, m, rng, truth)
    elif effect == "multipath" and form == "A":
        q = _mirror(ctx, q, sig, m, truth)
    elif effect == "multipath":
        q = _patch_relay(ctx, q, sig, m, rng, truth)
    elif effect == "readout_pattern":
        q = _readout(ctx, q, form, m, rng)
    x = np.arange(d.shape[1])
    t1 = np.random.default_rng([ctx["seed"], 3]).uniform(0, 2 * np.pi)
    pat = cam.fpn[0] * np.cos(2 * np.pi * x / 3 + t1) + cam.fpn[1] * np.cos(np.pi * x)
    return q + pat[None, None, None, :] * np.cos(cam.thetas - cam.psi)[None, :, None, None]


def _full_well(q: np.ndarray, form: str, level: float) -> np.ndarray:
    if form == "A":
        return np.minimum(q, level)
    over = np.maximum(q - level, 0.0)
    return np.where(q > level, level + over / (1 + over / (KNEE_SOFT * level)), q)


def _jitter(ctx, form, m, rng) -> tuple[np.ndarray, np.ndarray]:
    """noise_floor: delay jitter (T, H, W) (m) and its sd map (H, W) (mm)."""
    t, (h, w) = ctx["frames"], ctx["d"].shape
    if form == "A":
        x = rng.standard_t(3, (t, h, w)) / math.sqrt(3.0)  # unit sd
        sd = np.full((h, w), m)
    else:
        prof = np.exp(0.6 * rng.standard_normal(w))
        sd = np.broadcast_to(m * prof / np.sqrt(np.mean(prof**2)), (h, w))
        x = rng.standard_normal((t, h, w))
    return x * sd[None] * 1e-3, np.asarray(sd)


def _impulses(ctx, dn, form, m, rng, truth) -> np.ndarray:
    t, n, h, w = dn.shape
    hit = np.zeros((t, h, w), bool)
    out = dn.copy()
    if form == "A":
        hot = rng.random((h, w)) < m / SALT_FIRE
        code = rng.uniform(0, 3000, (n, h, w)).round()
        hit = hot[None] & (rng.random((t, h, w)) < SALT_FIRE)
        out = np.where(hit[:, None], code[None], out)
        truth["hot_pixel_share"] = float(hot.mean())
    else:
        for _ in range(int(round(m * t * h * w / 14))):
            k, length = int(rng.integers(0, t)), int(rng.integers(4, 25))
            y, x = int(rng.integers(0, h)), int(rng.integers(0, w))
            sl = (
                (k, y, slice(x, x + length)) if rng.random() < 0.5 else (k, slice(y, y + length), x)
            )
            hit[sl] = True
            off = rng.uniform(-1500, 1500, n)
            seg = out[sl[0], :, sl[1], sl[2]]
            out[sl[0], :, sl[1], sl[2]] = np.clip(
                seg + off.reshape((n,) + (1,) * (seg.ndim - 1)), 0, 65535
            )
    truth["share_frame_pixels"] = float(hit.mean())
    return out


def _scene_for(d, effect, form, m, cam, truth) -> np.ndarray:
    """phase_wrapping: the scene recorded (stretched, or with a far room beyond R)."""
    if effect != "phase_wrapping":
        return d
    r, far = cam.range_m, np.quantile(d, 1 - m)
    if form == "A":
        d = d * (r / far)
    else:
        d = np.where(d >= far, r + 0.2 + 2.0 * (d - far), d)
    truth.update(range_m=r, share_beyond=float((d >= r).mean()))
    truth["beyond_excess_m_median"] = float(np.median(d[d >= r] - r)) if (d >= r).any() else 0.0
    return d


def _check(effect, form, magnitude) -> None:
    if effect is not None and effect not in EFFECTS:
        raise ValueError(f"effect must be None or one of {EFFECTS}, got {effect!r}")
    if form not in FORMS:
        raise ValueError(f"form must be one of {FORMS}, got {form!r}")
    if effect is not None and not magnitude > 0:
        raise ValueError(f"magnitude must be > 0 for an effect, got {magnitude!r}")


def _setup(depth, reflectance, effect, form, magnitude, frames, seed, info, camera):
    _check(effect, form, magnitude)
    cam = Camera(**camera)
    truth = {"effect": effect, "form": form if effect else None, "magnitude": magnitude}
    truth["expected_name"] = EXPECTED.get(effect) if effect else None
    d = _scene_for(np.asarray(depth, dtype=np.float64), effect, form, magnitude, cam, truth)
    rho = np.asarray(reflectance, dtype=np.float64)
    ctx = {"cam": cam, "d": d, "rho": rho, "frames": frames, "seed": seed, "info": info or {}}
    return ctx, truth


def _well_level(clean: np.ndarray, m: float) -> float:
    """saturation: the level that the brightest noise-free sample of a share ``m`` of the pixels
    (first frame) passes."""
    return float(np.quantile(clean[0].max(axis=0), 1 - m))


def noise_free(
    depth,
    reflectance,
    *,
    effect=None,
    form="A",
    magnitude=0.0,
    frames=24,
    seed=0,
    info=None,
    **camera,
) -> dict:
    """The expected samples of :func:`generate`'s recording (same arguments), without shot / read
    noise, rounding, jitter or impulses (the full well applied): ``samples`` (T, N, H, W) e-,
    decoded ``depth`` (m) and ``amplitude`` (e-), ``truth``, ``scene_depth``."""
    ctx, truth = _setup(depth, reflectance, effect, form, magnitude, frames, seed, info, camera)
    q = _expected(ctx, effect, form, magnitude, truth)
    if effect == "saturation":
        truth["level_e"] = _well_level(q, magnitude)
        q = _full_well(q, form, truth["level_e"])
    d, a = decode(q, ctx["cam"].frequency)
    return {"samples": q, "depth": d, "amplitude": a, "truth": truth, "scene_depth": ctx["d"]}


def generate(
    depth,
    reflectance,
    *,
    effect: str | None = None,
    form: str = "A",
    magnitude: float = 0.0,
    frames: int = 24,
    seed: int = 0,
    info: dict | None = None,
    **camera,
) -> dict:
    """One recording of the scene ``depth`` (radial, m), ``reflectance`` (H, W) with one effect
    (or none). ``info``: the scene's floor plane (from :func:`scene_model`), used by multipath A.
    ``camera``: overrides of :class:`Camera`.

    Returns a dict: ``depth`` (T, H, W) float32 m (NaN invalid), ``amplitude`` (T, H, W) float32
    DN, ``raw`` (T, N, H, W) float32 DN samples, ``meta`` (the recording meta), ``truth`` (what was
    planted: effect, form, magnitude, effect_size, snr, details), ``scene_depth`` (the scene
    recorded: differs from ``depth`` for phase_wrapping)."""
    ctx, truth = _setup(depth, reflectance, effect, form, magnitude, frames, seed, info, camera)
    cam = ctx["cam"]
    noise = np.random.default_rng([seed, 2])
    jitter = sd_add = None
    if effect == "noise_floor":
        jitter, sd_add = _jitter(ctx, form, magnitude, noise)
        if form == "B":
            truth["column_sd_mm"] = [float(v) for v in sd_add[0]]
    clean = _expected(ctx, effect, form, magnitude, truth)
    q = clean if jitter is None else _expected(ctx, effect, form, magnitude, truth, jitter)
    level = None
    if effect == "saturation":
        level = truth["level_e"] = _well_level(clean, magnitude)
        clean = _full_well(clean, form, level)
    q = noise.poisson(np.clip(q, 0, None)).astype(np.float64)
    q += noise.normal(0.0, cam.read_e, q.shape)
    if level is not None:
        truth["share_pixel_frames_over"] = float((q.max(axis=1) > level).mean())
        truth["share_samples_over"] = float((q > level).mean())
        q = _full_well(q, form, level)
    dn = np.clip(np.round(q / cam.gain), 0, 65535)
    if effect == "impulsive_pixels":
        dn = _impulses(ctx, dn, form, magnitude, noise, truth)
    depth_f, amp = decode(dn, cam.frequency)
    depth_f = np.where(depth_f > 0, depth_f, np.nan).astype(np.float32)
    if effect is not None:
        truth.update(_visibility(ctx, clean, effect, form, magnitude, truth, sd_add))
    meta = {
        "modulation_frequency_hz": cam.frequency,
        "integration_time_us": 300.0,
        "n_phases": cam.n_phases,
        "amplitude_unit": "DN",
        "source": "benchmarks/form_shifted_generator.py",
    }
    return {
        "depth": depth_f,
        "amplitude": amp.astype(np.float32),
        "raw": dn.astype(np.float32),
        "meta": meta,
        "truth": truth,
        "scene_depth": ctx["d"],
    }


def _visibility(ctx, clean, effect, form, m, truth, sd_add) -> dict:
    """Effect size and ``snr`` (module docstring) from the noise-free samples."""
    cam, t = ctx["cam"], ctx["frames"]
    null = _expected(ctx, None, "A", 0.0, {})
    d0, a0 = decode(null, cam.frequency)
    var = null.mean(axis=1) + cam.read_e**2 + cam.gain**2 / 12
    rel_sd = np.sqrt(2 * var / cam.n_phases) / a0  # per frame: phase (rad) = relative amplitude
    sd_d = rel_sd * C_AIR / (4 * np.pi * cam.frequency)
    kind = SNR_KIND.get(effect)
    out = {}
    if kind in ("depth", "amplitude", "drift"):
        d1, a1 = decode(clean, cam.frequency)
        r = cam.range_m
        dd = np.mod(d1 - d0 + r / 2, r) - r / 2
        if kind == "drift":
            frame = dd.mean(axis=(1, 2))
            z = np.sqrt(np.mean((frame - frame.mean()) ** 2)) / (sd_d.mean(0) / math.sqrt(t))
            return {
                "effect_size": float(np.ptp(frame) * 1e3),
                "effect_size_unit": "mm p-p",
                "snr": float(np.sqrt(np.mean(z**2))),
            }
        if kind == "depth":
            delta, sd, unit, scale = dd.mean(0), sd_d.mean(0), "mm RMS", 1e3
        else:
            delta, sd, unit, scale = (a1 / a0 - 1).mean(0), rel_sd.mean(0), "relative RMS", 1.0
        mag = np.abs(delta)
        aff = (mag >= 0.1 * np.quantile(mag, 0.99)) & (mag > 0)
        if not aff.any():
            return {"effect_size": 0.0, "effect_size_unit": unit, "affected_share": 0.0, "snr": 0.0}
        z = mag[aff] / (sd[aff] / math.sqrt(t))
        out = {
            "effect_size": float(np.sqrt(np.mean(delta[aff] ** 2)) * scale),
            "effect_size_unit": unit,
            "affected_share": float(aff.mean()),
            "snr": float(np.sqrt(np.mean(z**2))) if z.size else 0.0,
        }
    elif kind == "noise":
        s0 = sd_d.mean(0) * 1e3
        z = sd_add**2 / (s0**2 * math.sqrt(2 / (t - 1)))
        out = {
            "effect_size": float(np.sqrt(np.mean(sd_add**2))),
            "effect_size_unit": "mm RMS",
            "snr": float(np.sqrt(np.mean(z**2))),
        }
    elif effect == "impulsive_pixels":
        out = {"effect_size": truth["share_frame_pixels"], "effect_size_unit": "frame-pixel share"}
    elif effect == "saturation":
        out = {"effect_size": truth["share_pixel_frames_over"], "effect_size_unit": "pixel share"}
    elif effect == "phase_wrapping":
        out = {"effect_size": truth["share_beyond"], "effect_size_unit": "scene share"}
    if effect == "flying_pixels" and form == "A":
        out["effect_size_share"] = truth["mixed_share"]
    return out
