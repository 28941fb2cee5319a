"""The held-out part of the literature generator: further forms of every family, other scenes.

Same camera as ``benchmarks/literature_generator.py`` (its chain, its decoding); the forms below
are in neither that module nor elsewhere in the project, the scenes are new, and the seeds are
drawn from another stream (part code 1). Each form's docstring cites its source.

- saturation: ``sunlit_patch``, ``vertical_blooming``
- fpn_pattern: ``split_readout_halves``, ``tap_gain_mismatch``
- amplitude_bias: ``tanh_crossing``
- cyclic_error: ``phase_step_error``, ``distance_bspline``
- pixel_gain: ``dust_shadows``
- impulsive_pixels: ``transient_hits``
- vignetting: ``led_ring_offaxis``
- temporal_drift: ``fan_cycle``
- flying_pixels: ``tap_motion``
- multipath: ``glossy_side_wall``
- noise_floor: ``dual_dirac_jitter``
"""

from __future__ import annotations

import math

import numpy as np
from literature_generator import (
    C0,
    F_MOD,
    FULL_WELL,
    M_PER_RAD,
    N_PHASES,
    RANGE_M,
    Box,
    Plan,
    Plane,
    SceneSpec,
    Sphere,
    _checker,
    _const,
    _rays,
    _share_above,
    _stripes,
    _value_noise,
    base_signal,
    cast,
    dn_for_visibility,
    generate_with,
)
from scipy import interpolate, ndimage

# ----------------------------------------------------------------------------------------------
# scenes
# ----------------------------------------------------------------------------------------------


def scene_shelves(rng):
    """A shelf wall 2.6-3.4 m away with books (boxes of many reflectances) on 3 boards."""
    depth = rng.uniform(2.6, 3.4)
    half_w = rng.uniform(1.5, 1.9)
    floor = -rng.uniform(0.9, 1.2)
    prims = [
        Plane((0, 0, depth), (0, 0, -1), _const(rng.uniform(0.5, 0.8))),
        Plane((0, floor, 0), (0, 1, 0), _stripes(0.25, 0.4, 0.3, 2)),
        Plane((0, 1.5, 0), (0, -1, 0), _const(0.7)),
        Plane((-half_w, 0, 0), (1, 0, 0), _const(rng.uniform(0.4, 0.7))),
        Plane((half_w, 0, 0), (-1, 0, 0), _const(rng.uniform(0.4, 0.7))),
    ]
    for y in (-0.6, 0.0, 0.6):
        prims.append(Box((-1.2, y - 0.03, depth - 0.35), (1.2, y, depth), _const(0.6)))
        x = -1.15
        while x < 1.1:
            bw = rng.uniform(0.04, 0.12)
            bh = rng.uniform(0.2, 0.45)
            bd = rng.uniform(0.18, 0.3)
            prims.append(
                Box((x, y, depth - bd), (x + bw, y + bh, depth), _const(rng.uniform(0.05, 0.95)))
            )
            x += bw + rng.uniform(0.0, 0.05)
    return SceneSpec("shelves", prims, floor_y=floor, side_x=half_w)


def scene_stairs(rng):
    """A staircase rising away from the camera (steps 0.17 m high, 0.28 m deep) in a stairwell."""
    floor = -rng.uniform(1.2, 1.5)
    z0 = rng.uniform(1.3, 2.0)
    half_w = rng.uniform(0.9, 1.3)
    prims = [
        Plane((0, floor, 0), (0, 1, 0), _const(0.3)),
        Plane((0, 0, 5.2), (0, 0, -1), _const(0.6)),
        Plane((0, 1.8, 0), (0, -1, 0), _const(0.7)),
        Plane((-half_w, 0, 0), (1, 0, 0), _value_noise(rng, 0.3, 0.8, 0.3, (2, 1))),
        Plane((half_w, 0, 0), (-1, 0, 0), _const(0.55)),
    ]
    rho_a, rho_b = rng.uniform(0.1, 0.4), rng.uniform(0.5, 0.9)
    for i in range(12):
        z = z0 + 0.28 * i
        if z > 5.0:
            break
        prims.append(
            Box(
                (-half_w, floor, z),
                (half_w, floor + 0.17 * (i + 1), 5.2),
                _const(rho_a if i % 2 == 0 else rho_b),
            )
        )
    return SceneSpec("stairs", prims, floor_y=floor, side_x=half_w)


def scene_lobby(rng):
    """A wide hall with square pillars (0.3-0.5 m) at 1.5-4.5 m and a glass-free far wall."""
    floor = -rng.uniform(1.1, 1.4)
    half_w = rng.uniform(2.0, 2.3)
    depth = rng.uniform(4.6, 5.0)
    prims = [
        Plane((0, 0, depth), (0, 0, -1), _checker(0.3, 0.8, 0.6)),
        Plane((0, floor, 0), (0, 1, 0), _checker(0.15, 0.5, 0.6, (0, 2))),
        Plane((0, 1.7, 0), (0, -1, 0), _const(0.8)),
        Plane((-half_w, 0, 0), (1, 0, 0), _const(0.5)),
        Plane((half_w, 0, 0), (-1, 0, 0), _const(0.5)),
    ]
    for _ in range(rng.integers(3, 6)):
        z = rng.uniform(1.5, 4.5)
        x = rng.uniform(-0.55, 0.55) * z
        s = rng.uniform(0.15, 0.25)
        prims.append(Box((x - s, floor, z - s), (x + s, 1.7, z + s), _const(rng.uniform(0.2, 0.9))))
    if rng.uniform() < 0.5:
        prims.append(
            Sphere(
                (rng.uniform(-0.5, 0.5), floor + 0.4, rng.uniform(1.2, 2.0)),
                0.3,
                _const(rng.uniform(0.1, 0.9)),
            )
        )
    return SceneSpec("lobby", prims, floor_y=floor, side_x=half_w)


HELDOUT_SCENES = {"shelves": scene_shelves, "stairs": scene_stairs, "lobby": scene_lobby}


# ----------------------------------------------------------------------------------------------
# forms
# ----------------------------------------------------------------------------------------------


def sat_sunlit_patch(ctx, rng):
    """Background-light saturation: a sunlit patch (a window's light on the scene, an ellipse
    covering a share p = 3-10 % of the pixels) adds 1-1.6 full wells of unmodulated electrons to
    every sample, so all four samples clip and the pixel's amplitude collapses. T. Moller, H.
    Kraft, J. Frey, M. Albrecht, R. Lange, "Robust 3D measurement with PMD sensors", Proc. 1st
    Range Imaging Research Day, ETH Zurich 2005, sec. 2 (background light saturating the pixel;
    the SBI circuit as the remedy)."""
    p = rng.uniform(0.03, 0.10)
    yy, xx = np.mgrid[0 : ctx.h, 0 : ctx.w]
    cy, cx = rng.uniform(0.2, 0.8) * ctx.h, rng.uniform(0.2, 0.8) * ctx.w
    ar = rng.uniform(0.5, 2.0)
    rad = math.sqrt(p * ctx.h * ctx.w / (np.pi * ar))
    inside = ((yy - cy) / rad) ** 2 + ((xx - cx) / (rad * ar)) ** 2 <= 1
    soft = ndimage.gaussian_filter(inside.astype(float), 1.5)
    level = rng.uniform(1.0, 1.6) * FULL_WELL
    sun = level * soft * ctx.geom["rho"] / np.median(ctx.geom["rho"][inside])
    return (
        Plan(dark_extra=sun[None]),
        p,
        "share of pixels in the sun patch",
        {"sun_e_per_sample": level, "patch_pixels": int(inside.sum())},
    )


def sat_vertical_blooming(ctx, rng):
    """Blooming: charge above the well capacity spills into the two vertical neighbours (half
    each) before the well clip, so the saturated area grows along the columns; exposure raised
    until a share p = 3-10 % of the samples overflows. J. R. Janesick, "Scientific
    Charge-Coupled Devices", SPIE Press 2001, sec. 4.2 (blooming along the column); EMVA 1288
    Rel. 4.0, sec. 2.1 (saturation)."""
    p = rng.uniform(0.03, 0.10)
    lo, hi = 1.0, 100.0
    for _ in range(50):
        mid = math.sqrt(lo * hi)
        if _share_above(ctx, mid, FULL_WELL) < p:
            lo = mid
        else:
            hi = mid

    def resp(e):
        ex = np.maximum(e - FULL_WELL, 0.0)
        out = np.minimum(e, FULL_WELL)
        out[..., 1:, :] += 0.5 * ex[..., :-1, :]
        out[..., :-1, :] += 0.5 * ex[..., 1:, :]
        return out

    return (
        Plan(exposure=hi, response=resp),
        p,
        "share of samples above the well",
        {"exposure_factor": hi},
    )


def fpn_split_readout_halves(ctx, rng):
    """Split read-out: the top and the bottom half of the array are converted by two banks of
    column ADCs (one bank at each edge), each column of each bank with its own offset per sample
    (s DN, set for 4-8 x the temporal-mean noise at the median pixel) and each bank with a common
    offset (2-3 s): a seam at mid-height and two
    unrelated column patterns. C. S. Bamji et al., "A 0.13 um CMOS system-on-chip for a 512x424
    time-of-flight image sensor with multi-frequency photo-demodulation up to 130 MHz and 2 GS/s
    ADC", IEEE JSSC 50(1), 2015, sec. III (the array read out to the top and the bottom)."""
    s = dn_for_visibility(ctx, rng.uniform(4.0, 8.0), 1 / math.sqrt(2))
    half = ctx.h // 2
    off = np.zeros((N_PHASES, ctx.h, ctx.w))
    for sl in (slice(0, half), slice(half, ctx.h)):
        bank = rng.uniform(2, 3) * s * rng.standard_normal((N_PHASES, 1, 1))
        off[:, sl, :] = bank + s * rng.standard_normal((N_PHASES, 1, ctx.w))
    return Plan(offset_dn=off), s, "DN rms per column and sample", {"column_offset_rms_dn": s}


def fpn_tap_gain_mismatch(ctx, rng):
    """Tap gain mismatch: each pixel's taps (its two read-out nodes for samples 0/180 and 90/270
    deg) have their own conversion gains, 1 + s z_kij, s = 1-3 %, so every pixel carries a fixed
    complex offset proportional to its DC level (the ambient light shows through). R. Schwarte,
    Z. Xu, H.-G. Heinol, J. Olk, R. Klein, B. Buxbaum, H. Fischer, J. Schulte, "New
    electro-optical mixing and correlating sensor: facilities and applications of the photonic
    mixer device (PMD)", Proc. SPIE 3100, 1997 (the two-tap PMD pixel); EMVA 1288 Rel. 4.0, sec.
    4.5 (PRNU, here per tap)."""
    s = rng.uniform(0.01, 0.03)
    g = 1 + s * rng.standard_normal((N_PHASES, ctx.h, ctx.w))

    def resp(e):
        return e * g

    return Plan(response=resp), s, "relative gain rms per tap", {"tap_gain_rms": s}


def ab_tanh_crossing(ctx, rng):
    """A signed intensity-related error crossing zero: delta_d = b tanh((ln A_m - ln A) / w), A_m
    the median amplitude, w = 0.7-1.5, b = 3-8 cm (dark pixels measured too far, bright ones too
    near, or the reverse). M. Lindner and A. Kolb, "Calibration of the intensity-related distance
    error of the PMD TOF-camera", Proc. SPIE 6764, 2007, fig. 4 (the measured error changes sign
    over the intensity range)."""
    b = rng.uniform(0.03, 0.08) * (1 if rng.uniform() < 0.5 else -1)
    wdt = rng.uniform(0.7, 1.5)
    am = float(np.median(ctx.amp0_dn))
    d = b * np.tanh((math.log(am) - np.log(np.maximum(ctx.amp0_dn, 1e-6))) / wdt)
    return Plan(phase=d / M_PER_RAD), abs(b), "m at the extremes", {"b_m": b, "w": wdt}


def ce_phase_step_error(ctx, rng):
    """Phase-step errors: the four sampling phases are off by fixed errors eps_k (rms 0.04-0.1
    rad, the same in every pixel and frame), which gives a depth error of period R / 2 (twice the
    phase frequency) instead of the harmonics' R / 4. J. Schwider, R. Burow, K.-E. Elssner, J.
    Grzanna, R. Spolaczyk, K. Merkel, "Digital wave-front measuring interferometry: some
    systematic error sources", Applied Optics 22(21), 1983, sec. 3 (phase-shifter miscalibration,
    error at twice the fringe frequency)."""
    s = rng.uniform(0.04, 0.10)
    eps = s * rng.standard_normal(N_PHASES)
    eps -= eps.mean()
    return (
        Plan(theta=eps[:, None, None]),
        s,
        "rad rms phase-step error",
        {"eps_rad": [float(e) for e in eps]},
    )


def ce_distance_bspline(ctx, rng):
    """A systematic distance error given by a cubic B-spline over the distance (control points
    every 0.4 m, values ~ N(0, b), b = 2-5 cm), not periodic. M. Lindner and A. Kolb, "Lateral
    and depth calibration of PMD-distance sensors", ISVC 2006, LNCS 4292, sec. 4.2 (the distance
    error as a B-spline of the distance)."""
    b = rng.uniform(0.02, 0.05)
    knots = np.arange(0.0, RANGE_M + 0.4, 0.4)
    vals = b * rng.standard_normal(len(knots))
    spl = interpolate.make_interp_spline(knots, vals, k=3)
    d = spl(ctx.geom["r"])
    return (
        Plan(phase=d / M_PER_RAD),
        b,
        "m rms of the control points",
        {"depth_rms_m": float(d.std())},
    )


def pg_dust_shadows(ctx, rng):
    """Dust on the sensor's cover glass: 3-8 soft shadows, gain 1 - a exp(-d^2 / 2 s^2), a = 0.1-0.3,
    s = 2-6 px, on all photo-electrons. C. Zhou and S. Lin, "Removal of image artifacts due to
    sensor dust", CVPR 2007, sec. 3 (the dust's attenuation function)."""
    n = int(rng.integers(3, 9))
    yy, xx = np.mgrid[0 : ctx.h, 0 : ctx.w]
    g = np.ones((ctx.h, ctx.w))
    amax = 0.0
    for _ in range(n):
        a = rng.uniform(0.1, 0.3)
        s = rng.uniform(2.0, 6.0)
        cy, cx = rng.uniform(0, ctx.h), rng.uniform(0, ctx.w)
        g *= 1 - a * np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / (2 * s * s))
        amax = max(amax, a)
    return Plan(gain_light=g), n, "dust particles", {"max_attenuation": amax}


def imp_transient_hits(ctx, rng):
    """Transient hits (particle/cosmic-ray events): per frame a Poisson number (mean 5-20) of
    hits, each depositing 10-60 ke- into one sample of 1-3 neighbouring pixels, never in the same
    place twice. A. J. P. Theuwissen, "Influence of terrestrial cosmic rays on the reliability of
    CCD image sensors - Part 1: experiments at room temperature", IEEE Trans. Electron Devices
    54(12), 2007, sec. III (transient events in the dark frames)."""
    lam = rng.uniform(5, 20)
    dark = np.zeros((ctx.t, N_PHASES, ctx.h, ctx.w))
    total = 0
    for ti in range(ctx.t):
        for _ in range(int(rng.poisson(lam))):
            y, x = int(rng.integers(0, ctx.h)), int(rng.integers(0, ctx.w))
            k = int(rng.integers(0, N_PHASES))
            q = rng.uniform(10000, 60000)
            ln = int(rng.integers(1, 4))
            horiz = rng.uniform() < 0.5
            for j in range(ln):
                yy, xx = (y, min(x + j, ctx.w - 1)) if horiz else (min(y + j, ctx.h - 1), x)
                dark[ti, k, yy, xx] += q / ln
            total += 1
    return Plan(dark_extra=dark, temporal=True), lam, "mean hits per frame", {"hits": total}


def vig_led_ring_offaxis(ctx, rng):
    """Illumination by 2-4 LEDs beside the lens, each tilted outwards by 8-20 deg with its own
    power (+-15 %), each a generalised Lambertian cos^m (half angle 25-40 deg): a non-radial,
    lobed profile on the modulated light. I. Moreno, M. Avendano-Alejo, R. I. Tzonchev, "Designing
    light-emitting diode arrays for uniform near-field irradiance", Applied Optics 45(10), 2006,
    eqs. (1)-(3) (the sum of tilted Lambertian lobes)."""
    n = int(rng.integers(2, 5))
    d = _rays(ctx.h, ctx.w)
    th = math.radians(rng.uniform(25, 40))
    m = -math.log(2) / math.log(math.cos(th))
    tilt = math.radians(rng.uniform(8, 20))
    rot0 = rng.uniform(0, 2 * np.pi)
    prof = np.zeros((ctx.h, ctx.w))
    for i in range(n):
        az = rot0 + 2 * np.pi * i / n
        ax = np.array(
            [math.sin(tilt) * math.cos(az), math.sin(tilt) * math.sin(az), math.cos(tilt)]
        )
        prof += rng.uniform(0.85, 1.15) * np.clip(d @ ax, 0, 1) ** m
    prof /= prof.max()
    return Plan(gain_active=prof), n, "LEDs", {"min_relative": float(prof.min()), "m": m}


def td_fan_cycle(ctx, rng):
    """A periodic drift from a thermostat/fan cycle: delta_d(t) = b sin(2 pi t / P + p0), P = 8-16
    frames, b = 6-12 x the temporal-mean noise at the median pixel (typically 2-5 cm), with the LED power following the temperature (+-1-3 %). The LED delay's
    temperature dependence: S. Seiter, et al., "Correction of the temperature induced error of the
    illumination source in a time-of-flight distance measurement setup", IEEE Sensors
    Applications Symposium 2013, sec. II; the periodic temperature is this generator's design."""
    b = rng.uniform(6.0, 12.0) * float(np.median(ctx.noise_mean_m))
    per = rng.uniform(8, 16)
    p0 = rng.uniform(0, 2 * np.pi)
    pw = rng.uniform(0.01, 0.03)
    s = np.sin(2 * np.pi * np.arange(ctx.t) / per + p0)
    return (
        Plan(
            phase=(b * s / M_PER_RAD)[:, None, None, None],
            gain_active=(1 - pw * s)[:, None, None, None],
        ),
        b,
        "m amplitude",
        {"period_frames": per, "power_swing": pw},
    )


def fp_tap_motion(ctx, rng):
    """Motion between the four sequential samples of a frame: the camera vibrates, each frame
    with its own lateral velocity v_t ~ N(0, s) px per sample (s = 0.3-0.8), so sample k sees the
    scene shifted by (k - 1.5) v_t; pixels on depth edges mix the surfaces sample by sample. M.
    Lindner and A. Kolb, "Compensation of motion artifacts for time-of-flight cameras", Dyn3D
    2009, LNCS 5742, sec. 2; S. Hussmann, A. Hermanski, T. Edeler, "Real-time motion artifact
    suppression in TOF camera systems", IEEE Trans. Instrum. Meas. 60(5), 2011."""
    s = rng.uniform(0.3, 0.8)
    v = s * rng.standard_normal((ctx.t, 2))

    def sig(c, ns):
        out = {n: np.zeros((c.t, N_PHASES, c.h, c.w), complex if n else float) for n in ns}
        for ti in range(c.t):
            for k in range(N_PHASES):
                sh = (float((k - 1.5) * v[ti, 0]), float((k - 1.5) * v[ti, 1]))
                g = cast(c.spec, c.h, c.w, shift=sh)
                b = base_signal(c, ns, geom=g)
                for n in ns:
                    out[n][ti, k] = b[n]
        return out

    return Plan(signal=sig), s, "px rms shift per sample", {"velocity_rms_px": s}


def mp_glossy_side_wall(ctx, rng):
    """A second path via a glossy side wall x = x_w (specular reflectance G = 0.2-0.5, a rough
    surface): source -> wall point F -> point P -> camera, F spread around the specular point F*
    (the source mirrored in the wall) with a Gaussian lobe of width s = 0.1-0.4 m on the wall
    (5 x 5 points); every path is at least as long as the specular one. K. E. Torrance and E. M.
    Sparrow, "Theory for off-specular reflection from roughened surfaces", JOSA 57(9), 1967 (the
    lobe around the specular direction); N. Naik, A. Kadambi, C. Rhemann, S. Izadi, R. Raskar,
    S. B. Kang, "A light transport model for mitigating multipath interference in time-of-flight
    sensors", CVPR 2015, sec. 3 (the sum of path phasors)."""
    gam = rng.uniform(0.2, 0.5)
    lobe = rng.uniform(0.1, 0.4)
    xw = ctx.spec.side_x * (1 if rng.uniform() < 0.5 else -1)
    g = ctx.geom
    p = g["points"]
    cm = np.array([2 * xw, 0.0, 0.0])
    v = cm - p
    l2 = np.linalg.norm(v, axis=-1)
    cos2 = np.clip(np.sum(g["normals"] * v, axis=-1) / l2, 0, 1)
    off_wall = np.abs(p[..., 0] - xw) > 1e-3
    e2 = np.where(off_wall, ctx.k_act * g["rho"] * gam * cos2 / l2**2, 0.0)
    s_hit = -xw / np.where(np.abs(p[..., 0] - 2 * xw) > 1e-9, p[..., 0] - 2 * xw, 1e-9)
    fstar = cm + s_hit[..., None] * (p - cm)
    offs = np.linspace(-2, 2, 5) * lobe
    wts = np.exp(-0.5 * (offs[:, None] ** 2 + offs[None, :] ** 2) / lobe**2)
    wts /= wts.sum()
    z2 = np.zeros(e2.shape, complex)
    for a, dy in enumerate(offs):
        for b, dz in enumerate(offs):
            f = fstar + np.array([0.0, dy, dz])
            length = np.linalg.norm(f, axis=-1) + np.linalg.norm(p - f, axis=-1) + g["r"]
            z2 += wts[a, b] * np.exp(1j * 2 * np.pi * F_MOD * length / C0)
    z2 = e2 * z2

    def sig(c, ns):
        s = base_signal(c, ns)
        return {
            n: s[n] + (e2 if n == 0 else np.abs(z2) * np.exp(1j * n * np.angle(z2))) for n in ns
        }

    return (
        Plan(signal=sig),
        gam,
        "specular reflectance of the wall",
        {"lobe_m": lobe, "median_second_to_direct": float(np.median(e2 / ctx.e_act))},
    )


def nf_dual_dirac_jitter(ctx, rng):
    """Dual-Dirac jitter: a deterministic jitter of +-DJ/2 (two equally likely values) plus a
    Gaussian random jitter RJ = 0.3 DJ / 2, per pixel and frame, independent of the amplitude; the
    total rms 2.5-5 x the per-frame phase noise at the median pixel. R. Stephens, "Jitter analysis: the dual-Dirac model, RJ/DJ, and
    Q-scale", Agilent Technologies white paper 5989-3206EN, 2004, sec. 2."""
    tot = rng.uniform(2.5, 5.0) * float(np.median(ctx.noise_mean_m / M_PER_RAD)) * math.sqrt(ctx.t)
    dj = 2 * tot / math.sqrt(1 + 0.3**2)
    rj = 0.3 * dj / 2
    sgn = rng.choice([-1.0, 1.0], size=(ctx.t, 1, ctx.h, ctx.w))
    ph = sgn * dj / 2 + rj * rng.standard_normal((ctx.t, 1, ctx.h, ctx.w))
    return Plan(phase=ph, temporal=True), dj, "rad peak-to-peak DJ", {"rj_rad": rj}


HELDOUT_FORMS = {
    "saturation": {"sunlit_patch": sat_sunlit_patch, "vertical_blooming": sat_vertical_blooming},
    "fpn_pattern": {
        "split_readout_halves": fpn_split_readout_halves,
        "tap_gain_mismatch": fpn_tap_gain_mismatch,
    },
    "amplitude_bias": {"tanh_crossing": ab_tanh_crossing},
    "cyclic_error": {
        "phase_step_error": ce_phase_step_error,
        "distance_bspline": ce_distance_bspline,
    },
    "pixel_gain": {"dust_shadows": pg_dust_shadows},
    "impulsive_pixels": {"transient_hits": imp_transient_hits},
    "vignetting": {"led_ring_offaxis": vig_led_ring_offaxis},
    "temporal_drift": {"fan_cycle": td_fan_cycle},
    "flying_pixels": {"tap_motion": fp_tap_motion},
    "multipath": {"glossy_side_wall": mp_glossy_side_wall},
    "noise_floor": {"dual_dirac_jitter": nf_dual_dirac_jitter},
}

SEED0 = 500_000  # the held-out recordings' first seed (the dev part starts at 0)

__all__ = ["HELDOUT_FORMS", "HELDOUT_SCENES", "SEED0", "generate"]


def generate(family, form, seed, size=(120, 160, 24)):
    """A held-out recording (``family`` in HELDOUT_FORMS or "none"/"null"), deterministic per seed."""
    return generate_with(HELDOUT_FORMS, HELDOUT_SCENES, family, form, seed, size, "heldout")
