"""The second held-out part of the literature generator: further forms of every family, new scenes.

Same camera as ``benchmarks/literature_generator.py`` (its chain, its decoding, its recording dict
and ``truth``, with the effect's size against the camera noise in ``truth["stats"]``); the forms
below are in neither that module nor ``benchmarks/literature_heldout.py``, they differ from those in
kind (where in the chain they act, their spatial or temporal structure, their functional shape),
the scenes are new (a doorway into a second room, a desk seen from above, a warehouse aisle with
round pillars) and the seeds come from another stream (part code 2). Each form's docstring cites
its source; section numbers are given as remembered by the author of this module, the works
themselves are the reference. Where a form's size in its own units depends on the scene's signal
level, its magnitude is drawn as a multiple of the camera's noise at the median pixel (stated in
the docstring) and reported in physical units.

- saturation: ``column_adc_clip``, ``ambient_full_well``, ``differential_clip``
- fpn_pattern: ``ar_column_pixel``, ``emi_fringe``
- amplitude_bias: ``bright_end``, ``inverse_power``
- cyclic_error: ``led_rc_pulse``, ``subframe_power_droop``
- pixel_gain: ``demod_contrast_map``, ``nir_fringing``
- impulsive_pixels: ``stuck_taps``, ``adc_sparkle_codes``
- vignetting: ``barrel_clip``, ``flat_top_diffuser``
- temporal_drift: ``phase_random_walk``, ``hotspot_overshoot``
- flying_pixels: ``defocus_disc``, ``pixel_crosstalk``
- multipath: ``subsurface_objects``, ``translucent_sheet``
- noise_floor: ``source_intensity_noise``, ``row_clock_jitter``
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from literature_generator import (
    ADC_MAX,
    BLACK_DN,
    C0,
    CONV_GAIN,
    DARK_E,
    F_MOD,
    FULL_WELL,
    HFOV_DEG,
    M_PER_RAD,
    MOD_CONTRAST,
    N_PHASES,
    Box,
    Plan,
    Plane,
    SceneSpec,
    Sphere,
    _checker,
    _const,
    _posters,
    _rays,
    _stripes,
    _value_noise,
    base_signal,
    cast,
    dn_for_visibility,
    field_angle,
    generate_with,
    noise_rad,
)
from scipy import ndimage, signal

# ----------------------------------------------------------------------------------------------
# scenes
# ----------------------------------------------------------------------------------------------


@dataclass
class Cylinder:
    """A vertical (y-axis) cylinder between y0 and y1, closed by flat caps."""

    center_xz: tuple
    radius: float
    y0: float
    y1: float
    tex: object

    def hit(self, o, d):
        cx, cz = self.center_xz
        ox, oz = o[0] - cx, o[2] - cz
        a = d[:, 0] ** 2 + d[:, 2] ** 2
        b = ox * d[:, 0] + oz * d[:, 2]
        c = ox * ox + oz * oz - self.radius**2
        disc = b * b - a * c
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (-b - np.sqrt(np.maximum(disc, 0.0))) / a
        y = o[1] + t * d[:, 1]
        ok = (disc > 0) & (a > 1e-12) & (t > 1e-6) & (y >= self.y0) & (y <= self.y1)
        t_side = np.where(ok, t, np.inf)
        # the caps (seen from above or below)
        t_cap = np.full(len(d), np.inf)
        for yc in (self.y0, self.y1):
            with np.errstate(divide="ignore", invalid="ignore"):
                tc = (yc - o[1]) / d[:, 1]
            px = o[0] + tc * d[:, 0] - cx
            pz = o[2] + tc * d[:, 2] - cz
            inside = (tc > 1e-6) & np.isfinite(tc) & (px * px + pz * pz <= self.radius**2)
            t_cap = np.where(inside & (tc < t_cap), tc, t_cap)
        t_best = np.minimum(t_side, t_cap)
        p = o + d * np.where(np.isfinite(t_best), t_best, 0.0)[:, None]
        n_side = np.stack([p[:, 0] - cx, np.zeros(len(d)), p[:, 2] - cz], 1) / self.radius
        n_cap = np.zeros_like(d)
        n_cap[:, 1] = -np.sign(d[:, 1])
        normal = np.where((t_cap < t_side)[:, None], n_cap, n_side)
        return t_best, normal


def _enclosure(rng, depth, half_w, floor, ceil, back_tex):
    return [
        Plane((0, 0, depth), (0, 0, -1), back_tex),
        Plane((0, floor, 0), (0, 1, 0), _value_noise(rng, 0.2, 0.5, 0.5, (0, 2))),
        Plane((0, ceil, 0), (0, -1, 0), _const(rng.uniform(0.55, 0.85))),
        Plane((-half_w, 0, 0), (1, 0, 0), _const(rng.uniform(0.35, 0.75))),
        Plane((half_w, 0, 0), (-1, 0, 0), _stripes(0.3, rng.uniform(0.5, 0.8), 0.7, 2)),
    ]


def scene_doorway(rng):
    """A front wall 2-2.7 m away with an open doorway into a second room (back wall 4.6-5.2 m), a
    box in the second room and a round column in front of the wall: large depth steps."""
    floor = -rng.uniform(1.0, 1.3)
    ceil = rng.uniform(1.2, 1.5)
    half_w = rng.uniform(1.8, 2.2)
    front = rng.uniform(2.0, 2.7)
    back = rng.uniform(4.6, 5.2)
    prims = _enclosure(rng, back, half_w, floor, ceil, _checker(0.35, 0.75, 0.45))
    x0 = rng.uniform(-0.8, 0.1)
    x1 = x0 + rng.uniform(0.8, 1.1)
    top = floor + rng.uniform(1.9, 2.1)
    wall = _const(rng.uniform(0.45, 0.85))
    prims += [
        Box((-half_w, floor, front), (x0, ceil, front + 0.15), wall),
        Box((x1, floor, front), (half_w, ceil, front + 0.15), wall),
        Box((x0, top, front), (x1, ceil, front + 0.15), wall),
    ]
    bx = rng.uniform(x0 + 0.1, x1 - 0.1)
    prims.append(
        Box(
            (bx - 0.25, floor, back - 1.2),
            (bx + 0.25, floor + rng.uniform(0.5, 1.0), back - 0.7),
            _const(rng.uniform(0.2, 0.9)),
        )
    )
    cx = rng.uniform(-1.0, 1.0)
    if abs(cx - 0.5 * (x0 + x1)) < 0.4:
        cx += 0.8
    prims.append(
        Cylinder((cx, rng.uniform(1.0, front - 0.5)), rng.uniform(0.1, 0.2), floor, ceil, wall)
    )
    prims.append(
        Sphere(
            (rng.uniform(-0.8, 0.8), floor + 0.25, rng.uniform(1.0, 1.6)),
            0.25,
            _const(rng.uniform(0.3, 0.95)),
        )
    )
    return SceneSpec("doorway", prims, floor_y=floor, side_x=half_w)


def scene_desk(rng):
    """Camera 0.6-0.8 m above a desk, pitched down 15-25 deg: a monitor, a mug (cylinder), a ball
    and a lamp base on the desk, a wall behind, the floor below the desk."""
    pitch = -rng.uniform(15, 25)
    floor = -rng.uniform(1.2, 1.4)
    desk_y = -rng.uniform(0.6, 0.8)
    wall = rng.uniform(1.8, 2.4)
    prims = [
        Plane((0, 0, wall), (0, 0, -1), _posters(_const(0.7), [(-0.6, -0.1, 0.0, 0.4, 0.15)])),
        Plane((0, floor, 0), (0, 1, 0), _const(0.3)),
        Plane((0, 1.5, 0), (0, -1, 0), _const(0.7)),
        Plane((-1.6, 0, 0), (1, 0, 0), _const(0.55)),
        Plane((1.6, 0, 0), (-1, 0, 0), _const(0.45)),
        Box(
            (-1.0, desk_y - 0.04, 0.3),
            (1.0, desk_y, wall),
            _value_noise(rng, 0.3, 0.6, 0.1, (0, 2)),
        ),
    ]
    mz = rng.uniform(wall - 0.6, wall - 0.3)
    mx = rng.uniform(-0.3, 0.3)
    prims.append(
        Box((mx - 0.3, desk_y + 0.1, mz), (mx + 0.3, desk_y + 0.45, mz + 0.03), _const(0.08))
    )
    prims.append(
        Box((mx - 0.04, desk_y, mz + 0.03), (mx + 0.04, desk_y + 0.1, mz + 0.1), _const(0.3))
    )
    prims.append(
        Cylinder(
            (rng.uniform(-0.6, -0.2), rng.uniform(0.8, 1.2)),
            0.045,
            desk_y,
            desk_y + 0.1,
            _const(rng.uniform(0.4, 0.95)),
        )
    )
    r = rng.uniform(0.05, 0.1)
    prims.append(
        Sphere((rng.uniform(0.2, 0.6), desk_y + r, rng.uniform(0.8, 1.3)), r, _const(0.85))
    )
    prims.append(
        Cylinder((rng.uniform(0.5, 0.8), mz - 0.1), 0.08, desk_y, desk_y + 0.03, _const(0.2))
    )
    return SceneSpec("desk", prims, pitch_deg=pitch, floor_y=floor, side_x=1.6)


def scene_aisle(rng):
    """A warehouse aisle: pallet stacks (boxes) on both sides, round pillars, an end wall 4.8-5.3
    m away."""
    floor = -rng.uniform(1.2, 1.5)
    ceil = rng.uniform(1.3, 1.6)
    half_w = rng.uniform(1.5, 1.8)
    end = rng.uniform(4.8, 5.3)
    prims = _enclosure(rng, end, half_w, floor, ceil, _value_noise(rng, 0.3, 0.8, 0.25))
    for side in (-1, 1):
        z = rng.uniform(0.8, 1.5)
        while z < end - 0.5:
            dz = rng.uniform(0.6, 1.0)
            hh = rng.uniform(0.4, 1.6)
            xin = side * rng.uniform(0.7, 1.0)
            lo = (min(xin, side * half_w), floor, z)
            hi = (max(xin, side * half_w), floor + hh, z + dz)
            prims.append(Box(lo, hi, _stripes(0.25, rng.uniform(0.5, 0.9), 0.12, 1)))
            z += dz + rng.uniform(0.05, 0.4)
    for _ in range(int(rng.integers(1, 3))):
        prims.append(
            Cylinder(
                (rng.uniform(-0.4, 0.4), rng.uniform(2.0, 4.2)),
                rng.uniform(0.12, 0.2),
                floor,
                ceil,
                _const(rng.uniform(0.3, 0.9)),
            )
        )
    return SceneSpec("aisle", prims, floor_y=floor, side_x=half_w)


HELDOUT2_SCENES = {"doorway": scene_doorway, "desk": scene_desk, "aisle": scene_aisle}


# ----------------------------------------------------------------------------------------------
# saturation
# ----------------------------------------------------------------------------------------------


def _bisect(fn, target, lo, hi, n=60):
    """x in [lo, hi] (log scale) where the increasing fn(x) crosses target."""
    for _ in range(n):
        mid = math.sqrt(lo * hi)
        if fn(mid) < target:
            lo = mid
        else:
            hi = mid
    return hi


def sat_column_adc_clip(ctx, rng):
    """Per-column ADC clip: every column's converter has its own full scale L_j (the column
    comparator's offset and the ramp's end; L_j = 52000 (1 - s u_j) DN, u_j ~ U(0, 1), s =
    0.1-0.3, all below the well's 55256 DN), the integration raised until a share p = 3-10 % of
    the noiseless samples reach their column's level; a sample clips at its column's level, not at
    a common one. M. F. Snoeij, A. J. P. Theuwissen, K. A. A. Makinwa, J. H. Huijsing, "Multiple-
    ramp column-parallel ADC architectures for CMOS image sensors", IEEE JSSC 42(12), 2007
    (single-slope column ADCs: the conversion range set per column by the comparator and the
    ramp); A. El Gamal and H. Eltoukhy, "CMOS image sensors", IEEE Circuits and Devices Magazine
    21(3), 2005 (column-parallel ADCs and their column-to-column mismatch)."""
    p = rng.uniform(0.03, 0.10)
    s = rng.uniform(0.1, 0.3)
    level = np.round(52000.0 * (1 - s * rng.uniform(0, 1, ctx.w)))

    def share(x):
        dn = (x * (ctx.mu0 - DARK_E) + DARK_E) * CONV_GAIN + BLACK_DN
        return float(np.mean(dn >= level))

    x = _bisect(share, p, 1.0, 100.0)

    def hook(dn):
        return np.minimum(dn, level)

    return (
        Plan(exposure=x, raw_hook=hook),
        p,
        "share of samples clipped",
        {
            "clip_level_min_dn": float(level.min()),
            "clip_level_max_dn": float(level.max()),
            "exposure_factor": x,
        },
    )


def _sun_irradiance(ctx, rng):
    """Unmodulated sunlight on the scene's surfaces: rho max(0, n . s) from a sun direction s high
    above the camera (cos of the incidence), plus a weak sky term (0.15 rho)."""
    el = math.radians(rng.uniform(35, 70))
    az = rng.uniform(0, 2 * np.pi)
    s = np.array([math.cos(el) * math.sin(az), math.sin(el), math.cos(el) * math.cos(az)])
    cos_sun = np.clip(ctx.geom["normals"] @ s, 0, 1)
    return ctx.geom["rho"] * (0.15 + cos_sun), s


def sat_ambient_full_well(ctx, rng):
    """Saturation set by the ambient light: sunlight (through a skylight) adds unmodulated
    electrons rho (0.15 + max(0, n . s)) to every sample, up to 25-50 % of the well on the most
    sunlit surfaces; the exposure (set on the modulated amplitude, which the ambient does not
    show) is raised until a share p = 3-10 % of the noiseless samples reach the 110 ke- well. The
    active light's headroom is the well minus the ambient, so where the sun falls the pixel clips
    at a lower active level, and mostly only the samples near the correlation's peak clip. R.
    Lange and P. Seitz, "Solid-state time-of-flight range camera", IEEE J. Quantum Electron.
    37(3), 2001 (background light fills the pixel's well and limits the dynamic range);
    T. Moller, H. Kraft, J. Frey, M. Albrecht, R. Lange, "Robust 3D measurement with PMD
    sensors", Range Imaging Research Day, ETH Zurich 2005, sec. 2."""
    p = rng.uniform(0.03, 0.10)
    irr, s = _sun_irradiance(ctx, rng)
    sun0 = irr * rng.uniform(0.25, 0.5) * FULL_WELL / float(irr.max())

    def share(x):
        return float(np.mean(x * (ctx.mu0 - DARK_E + sun0) + DARK_E > FULL_WELL))

    x = _bisect(share, p, 0.1, 100.0)
    sun = x * sun0
    return (
        Plan(exposure=x, dark_extra=sun[None]),
        p,
        "share of samples at the well",
        {
            "sun_e_max_per_sample": float(sun.max()),
            "sun_to_active_median": float(np.median(sun / np.maximum(x * ctx.e_act, 1e-9))),
            "exposure_factor": x,
            "sun_direction": [float(v) for v in s],
        },
    )


def sat_differential_clip(ctx, rng):
    """Differential read-out clip: the camera converts each tap pair's difference (samples 0-180
    and 90-270 deg) with its common mode removed, and the difference converter clips at +-L DN;
    L is the (1 - p) quantile of the noiseless half-differences, p = 3-10 % of the pairs clip. A
    clipped pair keeps its common mode and loses its difference: the amplitude stops growing and
    the phase is pulled towards the multiples of 45 deg. C. S. Bamji et al., "A 0.13 um CMOS
    system-on-chip for a 512x424 time-of-flight image sensor with multi-frequency photo-
    demodulation up to 130 MHz and 2 GS/s ADC", IEEE JSSC 50(1), 2015 (differential
    pixel, the tap difference digitised); EMVA Standard 1288 Rel. 4.0, 2021, sec. 2.1 (saturation
    as the converter's full scale)."""
    p = rng.uniform(0.03, 0.10)
    mu = ctx.mu0 * CONV_GAIN
    half = np.abs(np.stack([mu[0] - mu[2], mu[1] - mu[3]])) / 2
    lim = float(np.quantile(half, 1 - p))

    def hook(dn):
        out = dn.copy()
        for a, b in ((0, 2), (1, 3)):
            c = (dn[:, a] + dn[:, b]) / 2
            d = np.clip((dn[:, a] - dn[:, b]) / 2, -lim, lim)
            out[:, a] = c + d
            out[:, b] = c - d
        return out

    return (
        Plan(raw_hook=hook),
        p,
        "share of tap pairs clipped",
        {"difference_limit_dn": lim},
    )


# ----------------------------------------------------------------------------------------------
# fixed pattern
# ----------------------------------------------------------------------------------------------


def _ar1(rng, n, a, burn=64):
    """A unit-variance first-order autoregressive sequence x_i = a x_(i-1) + e_i."""
    e = rng.standard_normal(n + burn)
    x = signal.lfilter([1.0], [1.0, -a], e)[burn:]
    return x * math.sqrt(1 - a * a)


def _ar1_2d(rng, h, w, a_v, a_h, burn=32):
    """A separable (isotropic for a_v = a_h) first-order AR field, unit variance."""
    e = rng.standard_normal((h + burn, w + burn))
    x = signal.lfilter([1.0], [1.0, -a_h], e, axis=1)
    x = signal.lfilter([1.0], [1.0, -a_v], x, axis=0)[burn:, burn:]
    return x * math.sqrt((1 - a_h * a_h) * (1 - a_v * a_v))


def fpn_ar_column_pixel(ctx, rng):
    """Offset FPN as the sum of a column and a pixel component, each a first-order autoregressive
    random process (the column component AR(1) along the row, a = 0.3-0.8; the pixel component a
    separable 2-D AR(1), a = 0.2-0.6; the column share of the variance 30-70 %), drawn per tap
    and the same in every frame; the total rms s DN per sample set for 4-8 x the temporal-mean
    noise at the median pixel. A. El Gamal, B. A. Fowler, H. Min, X. Liu, "Modeling and
    estimation of FPN components in CMOS image sensors", Proc. SPIE 3301, 1998 (the
    column and pixel FPN components as first-order isotropic autoregressive processes)."""
    v = rng.uniform(4.0, 8.0)
    s = dn_for_visibility(ctx, v, 1 / math.sqrt(2))
    a_c = rng.uniform(0.3, 0.8)
    a_p = rng.uniform(0.2, 0.6)
    share = rng.uniform(0.3, 0.7)
    off = np.zeros((N_PHASES, ctx.h, ctx.w))
    for k in range(N_PHASES):
        col = _ar1(rng, ctx.w, a_c)[None, :]
        pix = _ar1_2d(rng, ctx.h, ctx.w, a_p, a_p)
        off[k] = s * (math.sqrt(share) * col + math.sqrt(1 - share) * pix)
    return (
        Plan(offset_dn=off),
        s,
        "DN rms per sample",
        {"offset_rms_dn": s, "a_column": a_c, "a_pixel": a_p, "column_share": share},
    )


def fpn_emi_fringe(ctx, rng):
    """A periodic offset pattern from an interferer locked to the read-out clock: a ripple of
    frequency f_r couples into the read-out chain and is sampled at each pixel's read-out time
    t_ij = (i W + j) t_pix, so each tap gets o_k = a cos(2 pi nu (i W + j) + psi_k) (nu = f_r
    t_pix mod 1 = 0.03-0.2 cycles per pixel: diagonal fringes; psi_k the tap's own read-out
    time), the same in every frame because the interferer is locked to the frame; a set for 4-8 x
    the temporal-mean noise at the median pixel. EMVA Standard 1288 Rel. 4.0, 2021 (the
    spectrogram of the non-uniformity, in which periodic disturbances show as peaks); the
    read-out-time model of the pattern is this generator's."""
    v = rng.uniform(4.0, 8.0)
    a = math.sqrt(2) * dn_for_visibility(ctx, v, 1 / math.sqrt(2))
    nu = rng.uniform(0.03, 0.2)
    ii, jj = np.mgrid[0 : ctx.h, 0 : ctx.w]
    n_pix = (ii * ctx.w + jj).astype(float)
    psi = rng.uniform(0, 2 * np.pi, N_PHASES)
    off = a * np.cos(2 * np.pi * nu * n_pix[None] + psi[:, None, None])
    return (
        Plan(offset_dn=off),
        a,
        "DN amplitude per sample",
        {"fringe_amplitude_dn": a, "cycles_per_pixel": nu, "target_visibility": v},
    )


# ----------------------------------------------------------------------------------------------
# amplitude bias
# ----------------------------------------------------------------------------------------------


def ab_bright_end(ctx, rng):
    """A bias only at the top of the amplitude range (the brightest 3-10 % of the pixels, still
    below saturation): delta_d = b ((A - A_q) / (A_max - A_q))^2 for A > A_q, 0 below, b = 2-6
    cm, mostly towards the camera (bright, near targets measured too near). D. Lefloch, R. Nair,
    F. Lenzen, H. Schafer, L. Streeter, M. J. Cree, R. Koch, A. Kolb, "Technical foundation and
    calibration methods for time-of-flight cameras", in Time-of-Flight and Depth Imaging, LNCS
    8200, Springer 2013 (intensity-related error); S. Foix, G. Alenya, C. Torras, "Lock-in
    time-of-flight (ToF) cameras: a survey", IEEE Sensors J. 11(9), 2011 (amplitude-related
    errors); the restriction to the bright end and the quadratic onset are this generator's
    parametrisation."""
    q = rng.uniform(0.90, 0.97)
    a = ctx.amp0_dn
    aq = float(np.quantile(a, q))
    amax = float(a.max())
    b = rng.uniform(0.02, 0.06)
    sign = -1.0 if rng.uniform() < 0.7 else 1.0
    shape = np.clip((a - aq) / (amax - aq), 0, None) ** 2
    d = sign * b * shape
    return (
        Plan(phase=d / M_PER_RAD),
        b,
        "m at the brightest pixel",
        {"amplitude_threshold_dn": aq, "share_affected": 1 - q, "sign": sign},
    )


def ab_inverse_power(ctx, rng):
    """A bias falling as a power of the amplitude: delta_d = b min((A_2 / A)^g, 3), g = 0.5-1.5,
    A_2 the 2nd amplitude percentile, b = 4-10 cm (a heavy tail into the mid amplitudes, unlike an
    exponential). S. Foix, G. Alenya, C. Torras, "Lock-in time-of-flight (ToF) cameras: a survey",
    IEEE Sensors J. 11(9), 2011 (amplitude-related errors, larger for weak returns); T.
    Kahlmann, F. Remondino, H. Ingensand, "Calibration for increased accuracy of the range imaging
    camera SwissRanger", ISPRS Comm. V Symposium 2006 (distance error against the reflectivity);
    the power law is this generator's parametrisation."""
    g = rng.uniform(0.5, 1.5)
    b = rng.uniform(0.04, 0.10)
    a = ctx.amp0_dn
    a2 = float(np.percentile(a, 2))
    sign = 1.0 if rng.uniform() < 0.7 else -1.0
    d = sign * b * np.minimum((a2 / np.maximum(a, 1e-9)) ** g, 3.0)
    return (
        Plan(phase=d / M_PER_RAD),
        b,
        "m at the 2nd amplitude percentile",
        {"exponent": g, "a2_dn": a2, "sign": sign, "bias_median_m": float(np.median(d))},
    )


# ----------------------------------------------------------------------------------------------
# cyclic error
# ----------------------------------------------------------------------------------------------


def rc_pulse_harmonics(duty, wtau, n_max=9):
    """Correlation harmonics a_n (complex, a_1 = 1) of a pulse of duty ``duty`` through a first-
    order LED response (omega tau = wtau), correlated with a 50 % square demodulation."""
    c = {}
    for n in range(1, n_max + 1, 2):
        light = math.sin(n * math.pi * duty) / n
        demod = (-1) ** ((n - 1) // 2) / n
        c[n] = light * demod / (1 + 1j * n * wtau)
    ph1 = np.angle(c[1])
    return {n: complex(v * np.exp(-1j * n * ph1) / abs(c[1])) for n, v in c.items()}


def ce_led_rc_pulse(ctx, rng):
    """Wiggling from a short light pulse through a slow LED: the illumination is a pulse of duty
    D = 0.15-0.28 (not a square) smoothed by the LED's first-order response (omega tau = 0.3-1),
    correlated with a 50 % square demodulation: harmonic n of the correlation is (sin(n pi D) / n)
    (+-1 / n) / (1 + i n omega tau), so the harmonics have their own phases and the depth error
    (3rd, 5th -> period R / 4; 7th, 9th -> R / 8) is skewed, not a symmetric sine; the global
    delay of the fundamental is calibrated out. M. Frank, M. Plaue, H. Rapp, U. Kothe, B. Jahne,
    F. A. Hamprecht, "Theoretical and experimental error analysis of continuous-wave time-of-flight
    range cameras", Optical Engineering 48(1), 2009 (systematic error from the higher
    harmonics of the correlation); E. F. Schubert, "Light-Emitting Diodes", 2nd ed., Cambridge
    Univ. Press 2006 (the LED's modulation response, limited by its carrier lifetime and
    capacitance: a first-order low-pass)."""
    duty = rng.uniform(0.15, 0.28)
    wtau = rng.uniform(0.3, 1.0)
    harm = rc_pulse_harmonics(duty, wtau)
    # the chain takes real harmonic weights; each harmonic's own phase goes into the signal
    mags = {n: abs(a) for n, a in harm.items()}
    rot = {n: np.exp(1j * np.angle(a)) for n, a in harm.items()}

    def sig(c, ns):
        b = base_signal(c, ns)
        return {n: (b[n] if n == 0 else b[n] * rot[n]) for n in ns}

    return (
        Plan(harmonics=mags, signal=sig),
        wtau,
        "omega tau of the LED",
        {"duty": duty, "a3_abs": abs(harm[3]), "a5_abs": abs(harm[5])},
    )


def ce_subframe_power_droop(ctx, rng):
    """Light power changing over the four sequential sub-frames: the LED heats during the
    sequence, sub-frame k emits (1 + kappa (k - 1.5)), kappa = +-1-3 % per sub-frame (the same in
    every frame and pixel). The unmodulated part of the light no longer cancels in the first DFT
    bin: a phase error sqrt(2) kappa / m sin(phi - phi_0) of period R (once per range) plus a
    weaker R / 2 term, independent of the amplitude. R. Lange, "3D time-of-flight distance
    measurement with custom solid-state image sensors in CMOS/CCD-technology", PhD thesis, Univ.
    Siegen 2000 (the four phase images acquired one after the other); M. Schmidt,
    "Analysis, modeling and dynamic optimization of 3D time-of-flight imaging systems", PhD
    thesis, Univ. Heidelberg 2011 (errors of the sequential acquisition when the signal
    changes between the phase images)."""
    kappa = rng.uniform(0.01, 0.03) * (1 if rng.uniform() < 0.5 else -1)
    g = 1 + kappa * (np.arange(N_PHASES) - 1.5)
    return (
        Plan(gain_active=g[:, None, None]),
        abs(kappa),
        "relative power step per sub-frame",
        {"kappa": kappa, "phase_error_peak_rad_approx": math.sqrt(2) * abs(kappa) / MOD_CONTRAST},
    )


# ----------------------------------------------------------------------------------------------
# pixel gain
# ----------------------------------------------------------------------------------------------


def pg_demod_contrast_map(ctx, rng):
    """Per-pixel demodulation contrast: each pixel separates the modulated charge with its own
    efficiency m_ij = m (1 + s z_ij), s = 3-8 %, the same in every frame; the modulated part of
    the samples (the amplitude) is scaled, the DC (ambient and the light's mean) is not, so it is
    a gain on the amplitude that the intensity image does not show. R. Lange and P. Seitz,
    "Solid-state time-of-flight range camera", IEEE J. Quantum Electron. 37(3), 2001
    (demodulation contrast); B. Buttgen, T. Oggier, M. Lehmann, R. Kaufmann, F. Lustenberger,
    "CCD/CMOS lock-in pixel for range imaging: challenges, limitations and state-of-the-art",
    Range Imaging Research Day, ETH Zurich 2005 (demodulation contrast of lock-in pixels);
    its spread over the pixels is modelled like a PRNU (EMVA 1288 Rel. 4.0, sec. 4.5)."""
    s = rng.uniform(0.03, 0.08)
    g = 1 + s * rng.standard_normal((ctx.h, ctx.w))

    def sig(c, ns):
        b = base_signal(c, ns)
        return {n: (b[n] if n == 0 else b[n] * g) for n in ns}

    return Plan(signal=sig), s, "relative rms of the contrast", {"contrast_rms": s}


def pg_nir_fringing(ctx, rng):
    """Near-infrared fringing: in a thinned (back-side illuminated) sensor the 850 nm light is
    reflected between the front and back of the thin silicon, so the response follows the local
    thickness t(x, y): g = 1 + a cos(4 pi n_Si t / lambda + phi_0), a = 3-10 %; t varies smoothly
    over the array (a smooth random field of 2-6 optical wavelengths peak to peak), giving contour
    fringes; on all light reaching the pixel. J. R. Janesick, "Scientific Charge-Coupled Devices",
    SPIE Press 2001 (quantum efficiency; interference fringing of thinned sensors in the
    near infrared); S. B. Howell, "Handbook of CCD Astronomy", 2nd ed., Cambridge Univ. Press
    2006 (fringing in the red and near infrared)."""
    a = rng.uniform(0.03, 0.10)
    cycles = rng.uniform(2.0, 6.0)
    field = ndimage.gaussian_filter(rng.standard_normal((ctx.h, ctx.w)), 0.25 * min(ctx.h, ctx.w))
    yy, xx = np.mgrid[0 : ctx.h, 0 : ctx.w]
    tilt = rng.uniform(-1, 1) * yy / ctx.h + rng.uniform(-1, 1) * xx / ctx.w
    field = field / np.ptp(field) + 0.5 * tilt
    field = (field - field.min()) / np.ptp(field)
    g = 1 + a * np.cos(2 * np.pi * cycles * field + rng.uniform(0, 2 * np.pi))
    return Plan(gain_light=g), a, "fringe contrast", {"fringe_cycles": cycles}


# ----------------------------------------------------------------------------------------------
# impulsive pixels
# ----------------------------------------------------------------------------------------------


def imp_stuck_taps(ctx, rng):
    """Partially stuck pixels: a share f = 0.3-1 % of the pixels has one tap whose output is
    stuck at a fixed code (stuck low at the black level, or at a random code 2-60 kDN), without
    noise and whatever the light, in every frame. J. Dudas, L. M. Wu, C. Jung, G. H. Chapman, Z.
    Koren, I. Koren, "Identification of in-field defect development in digital image sensors",
    Proc. SPIE 6502, 2007 (stuck-high, stuck-low and partially stuck pixels)."""
    f = rng.uniform(0.003, 0.01)
    n = max(1, int(round(f * ctx.h * ctx.w)))
    idx = rng.choice(ctx.h * ctx.w, n, replace=False)
    ys, xs = np.unravel_index(idx, (ctx.h, ctx.w))
    taps = rng.integers(0, N_PHASES, n)
    low = rng.uniform(size=n) < 0.4
    codes = np.where(low, BLACK_DN, np.round(rng.uniform(2000, 60000, n)))

    def hook(dn):
        out = dn.copy()
        out[:, taps, ys, xs] = codes
        return out

    return (
        Plan(raw_hook=hook),
        f,
        "share of pixels",
        {"n_pixels": n, "stuck_low": int(low.sum())},
    )


def imp_adc_sparkle_codes(ctx, rng):
    """ADC sparkle codes: now and then a conversion goes wrong (comparator metastability, a bit
    decided wrongly) and the output code has one of its upper bits (2^10-2^14 DN) flipped; each
    sample of each frame independently with probability r = 2-8 x 10^-4, so a few pixels per frame
    jump by a power of two, up or down, never twice in the same place on purpose. W. Kester (ed.),
    "The Data Conversion Handbook", Analog Devices / Newnes 2005 (sparkle codes and
    metastable comparator outputs); R. H. Walden, "Analog-to-digital converter survey and
    analysis", IEEE J. Sel. Areas Commun. 17(4), 1999 (comparator ambiguity)."""
    r = rng.uniform(2e-4, 8e-4)
    shape = (ctx.t, N_PHASES, ctx.h, ctx.w)
    hit = rng.uniform(size=shape) < r
    bit = rng.integers(10, 15, size=shape)
    mask = np.where(hit, 1 << bit, 0).astype(np.int64)

    def hook(dn):
        code = np.clip(np.round(dn), 0, ADC_MAX).astype(np.int64)
        return np.where(hit, (code ^ mask).astype(float), dn)

    return (
        Plan(raw_hook=hook, temporal=True),
        r,
        "probability per sample",
        {"events": int(hit.sum())},
    )


# ----------------------------------------------------------------------------------------------
# vignetting
# ----------------------------------------------------------------------------------------------


def _circle_overlap(r1, r2, d):
    """Area of the intersection of two circles (radii r1, r2, centres d apart)."""
    d = np.asarray(d, float)
    out = np.zeros_like(d)
    inside = d <= abs(r2 - r1)
    out[inside] = math.pi * min(r1, r2) ** 2
    part = (d > abs(r2 - r1)) & (d < r1 + r2)
    dd = d[part]
    a1 = r1 * r1 * np.arccos(np.clip((dd * dd + r1 * r1 - r2 * r2) / (2 * dd * r1), -1, 1))
    a2 = r2 * r2 * np.arccos(np.clip((dd * dd + r2 * r2 - r1 * r1) / (2 * dd * r2), -1, 1))
    a3 = 0.5 * np.sqrt(
        np.clip((-dd + r1 + r2) * (dd + r1 - r2) * (dd - r1 + r2) * (dd + r1 + r2), 0, None)
    )
    out[part] = a1 + a2 - a3
    return out


def vig_barrel_clip(ctx, rng):
    """Mechanical vignetting: off axis the lens barrel's rim cuts the entrance pupil; the light
    reaching the pixel is the overlap of the pupil (radius 1) and the rim's image (radius R =
    1.05-1.3) whose centre moves out as kappa tan(theta): full light up to theta_c = atan((R - 1)
    / kappa), then a steep loss; kappa set for a loss of 25-60 % in the corners; on all light
    reaching the pixel. N. Asada, A. Amano, M. Baba, "Photometric calibration of zoom lens
    systems", ICPR 1996 (vignetting as the overlap of the aperture and the lens rim); W.
    Yu, "Practical anti-vignetting methods for digital cameras", IEEE Trans. Consumer Electronics
    50(4), 2004 (mechanical vs natural vignetting)."""
    rr = rng.uniform(1.05, 1.3)
    loss = rng.uniform(0.25, 0.6)
    tan_a = np.tan(field_angle(ctx))
    tmax = float(tan_a.max())

    def corner_loss(kappa):
        return 1 - float(_circle_overlap(1.0, rr, np.array([kappa * tmax]))[0]) / math.pi

    kappa = _bisect(corner_loss, loss, 1e-3, 100.0)
    g = _circle_overlap(1.0, rr, kappa * tan_a) / math.pi
    th_c = math.degrees(math.atan((rr - 1) / kappa))
    return (
        Plan(gain_light=g),
        loss,
        "relative loss in the corners",
        {"rim_radius": rr, "onset_deg": th_c, "corner_falloff": float(1 - g.min())},
    )


def vig_flat_top_diffuser(ctx, rng):
    """A VCSEL behind a diffuser with a rectangular flat-top field of illumination: I = exp(-ln 2
    ((tan theta_x / tan alpha_x)^p + (tan theta_y / tan alpha_y)^p)), a super-Gaussian of order p =
    4-8, half-intensity half-angles alpha = 0.92-1.05 of the camera's half fields of view; flat in
    the middle, falling along the image's borders and most in the corners; on the modulated light
    only. F. M. Dickey and S. C. Holswade (eds.), "Laser Beam Shaping: Theory and Techniques",
    Marcel Dekker 2000 (flat-top profiles
    described as super-Gaussians); the rectangular field of illumination is this generator's
    choice for a diffuser matched to the sensor's aspect ratio."""
    p = rng.uniform(4.0, 8.0)
    d = _rays(ctx.h, ctx.w)
    tx = np.abs(d[..., 0] / d[..., 2])
    ty = np.abs(d[..., 1] / d[..., 2])
    hx = math.tan(math.radians(HFOV_DEG) / 2)
    hy = hx * ctx.h / ctx.w
    ax = rng.uniform(0.92, 1.05) * hx
    ay = rng.uniform(0.92, 1.05) * hy
    g = np.exp(-math.log(2) * ((tx / ax) ** p + (ty / ay) ** p))
    return (
        Plan(gain_active=g),
        p,
        "super-Gaussian order",
        {"alpha_x_deg": math.degrees(math.atan(ax)), "alpha_y_deg": math.degrees(math.atan(ay))},
    )


# ----------------------------------------------------------------------------------------------
# temporal drift
# ----------------------------------------------------------------------------------------------


def td_phase_random_walk(ctx, rng):
    """Wander of the modulation's phase: the delay between the light and the demodulation clock
    performs a random walk (the integral of white frequency noise of the clock/driver path), one
    step per frame, common to all pixels; the walk's rms over the record is 6-12 x the
    temporal-mean noise at the median pixel (the record's first frame at zero). D. W. Allan,
    "Statistics of atomic frequency standards", Proc. IEEE 54(2), 1966 (random-walk phase from
    white frequency noise); J. Rutman, "Characterization of phase and frequency instabilities in
    precision frequency sources: fifteen years of progress", Proc. IEEE 66(9), 1978."""
    b = rng.uniform(6.0, 12.0) * float(np.median(ctx.noise_mean_m))
    steps = rng.standard_normal(ctx.t)
    steps[0] = 0.0
    walk = np.cumsum(steps)
    walk = walk - walk[0]
    walk *= b / max(float(np.sqrt(np.mean(walk**2))), 1e-12)
    return (
        Plan(phase=(walk / M_PER_RAD)[:, None, None, None]),
        b,
        "m rms of the walk",
        {"walk_m": [float(v) for v in walk]},
    )


def td_hotspot_overshoot(ctx, rng):
    """Self-heating from a hot spot under the sensor (the illumination driver or the processor on
    the board) with a thermal regulation that sets in later: delta_d(t, x, y) = b S(x, y) g(t),
    S = 0.3 + 0.7 exp(-|x - x_h|^2 / 2 w^2) (w = 0.3-0.6 of the width), g(t) = (1 - e^(-t /
    tau_1)) - c (1 - e^(-t / tau_2)) scaled to peak 1 (tau_1 = 2-5 frames, tau_2 = 8-20, c =
    0.4-0.7: a rise, then a partial return); |b| = 6-12 x the temporal-mean noise at the median
    pixel. H. Sarbolandi, D. Lefloch, A. Kolb, "Kinect range sensing: structured-light versus
    time-of-flight Kinect", Computer Vision and Image Understanding 139, 2015 (pre-heating:
    the distance drifts until the device's temperature settles); P. Fuersattel et al., "A
    comparative error analysis of current time-of-flight sensors", IEEE Trans. Computational
    Imaging 2(1), 2016 (temperature drift); the two-time-constant curve and the spatial profile
    are this generator's parametrisation."""
    b = rng.uniform(6.0, 12.0) * float(np.median(ctx.noise_mean_m))
    b *= 1 if rng.uniform() < 0.5 else -1
    t1, t2 = rng.uniform(2, 5), rng.uniform(8, 20)
    c = rng.uniform(0.4, 0.7)
    tt = np.arange(ctx.t, dtype=float)
    g = (1 - np.exp(-tt / t1)) - c * (1 - np.exp(-tt / t2))
    g /= max(float(np.abs(g).max()), 1e-12)
    w = rng.uniform(0.3, 0.6) * ctx.w
    yh, xh = rng.uniform(0, ctx.h), rng.uniform(0, ctx.w)
    yy, xx = np.mgrid[0 : ctx.h, 0 : ctx.w]
    sp = 0.3 + 0.7 * np.exp(-((yy - yh) ** 2 + (xx - xh) ** 2) / (2 * w * w))
    d = b * g[:, None, None] * sp[None]
    return (
        Plan(phase=(d / M_PER_RAD)[:, None]),
        abs(b),
        "m peak drift at the hot spot",
        {"b_m": b, "tau1_frames": t1, "tau2_frames": t2, "return_share": c},
    )


# ----------------------------------------------------------------------------------------------
# flying pixels
# ----------------------------------------------------------------------------------------------


def _disc(radius):
    r = max(radius, 0.5)
    n = int(math.ceil(r))
    yy, xx = np.mgrid[-n : n + 1, -n : n + 1]
    k = np.clip(r + 0.5 - np.hypot(yy, xx), 0, 1)  # anti-aliased pillbox
    return k / k.sum()


def fp_defocus_disc(ctx, rng):
    """Defocus: the lens is focused at z_f (the scene's median depth x 0.6-1.2) and a point at
    depth z is spread over a disc of radius c |1 - z_f / z| pixels (thin-lens circle of confusion,
    c = 0.8-1.6 px at infinity, at most 4 px), so near objects' returns spill onto the far
    background behind their edges; computed by splatting depth layers (8 layers, 3 x 3
    sub-pixels) with their own discs, the complex signal summed. A. P. Pentland, "A new sense
    for depth of field", IEEE Trans. PAMI 9(4), 1987 (the blur circle's radius against the
    depth); J. P. Godbaz, M. J. Cree, A. A. Dorrington, "Understanding and ameliorating mixed
    pixels and multipath interference in AMCW lidar", in TOF Range-Imaging Cameras, Springer 2013
    (defocus mixing returns at edges)."""
    c = rng.uniform(0.8, 1.6)
    zf = float(np.median(ctx.geom["r"])) * rng.uniform(0.6, 1.2)

    def sig(cx, ns):
        s = 3
        g = cast(cx.spec, cx.h, cx.w, oversample=s)
        b = base_signal(cx, ns, geom=g)
        z = g["r"]
        edges = np.quantile(z, np.linspace(0, 1, 9))
        edges[-1] += 1e-9
        out = {n: np.zeros_like(b[n]) for n in ns}
        for i in range(8):
            lay = (z >= edges[i]) & (z < edges[i + 1])
            if not lay.any():
                continue
            zc = float(np.median(z[lay]))
            k = _disc(min(c * abs(1 - zf / zc), 4.0) * s)
            m = k.shape[0] // 2
            for n in ns:
                v = np.pad(np.where(lay, b[n], 0), m, mode="edge")
                out[n] = out[n] + signal.fftconvolve(v, k, mode="valid")
        return {n: v.reshape(cx.h, s, cx.w, s).mean(axis=(1, 3)) for n, v in out.items()}

    return (
        Plan(signal=sig),
        c,
        "px blur radius at infinity",
        {"focus_m": zf, "blur_radius_px_at_1m": c * abs(1 - zf)},
    )


def crosstalk_kernel(ah, av):
    """3 x 3 charge-sharing kernel: a share ah to each horizontal, av to each vertical and ah av
    to each diagonal neighbour, the rest kept."""
    k = np.array([[ah * av, av, ah * av], [ah, 0.0, ah], [ah * av, av, ah * av]])
    k[1, 1] = 1 - k.sum()
    return k


def fp_pixel_crosstalk(ctx, rng):
    """Inter-pixel crosstalk: photo-charge generated deep in the silicon (long near-infrared
    absorption length) diffuses into the neighbouring pixels, more along the rows than the columns
    (pixel layout): a share a_h = 4-10 % to each horizontal neighbour, a_v = (0.3-0.7) a_h to each
    vertical one, a_h a_v to the diagonals; it mixes the complex returns of neighbouring pixels on
    the pixel grid, so a pixel next to a bright near edge takes up its phase. G. Agranov, V.
    Berezin, R. H. Tsai, "Crosstalk and microlens study in a color CMOS image sensor", IEEE Trans.
    Electron Devices 50(1), 2003 (optical and electrical crosstalk between pixels); the
    row/column asymmetry is this generator's choice."""
    ah = rng.uniform(0.04, 0.10)
    av = ah * rng.uniform(0.3, 0.7)
    k = crosstalk_kernel(ah, av)

    def sig(c, ns):
        b = base_signal(c, ns)
        out = {}
        for n in ns:
            v = b[n]
            if np.iscomplexobj(v):
                out[n] = ndimage.convolve(v.real, k, mode="nearest") + 1j * ndimage.convolve(
                    v.imag, k, mode="nearest"
                )
            else:
                out[n] = ndimage.convolve(v, k, mode="nearest")
        return out

    return Plan(signal=sig), ah, "share to each horizontal neighbour", {"a_h": ah, "a_v": av}


# ----------------------------------------------------------------------------------------------
# multipath
# ----------------------------------------------------------------------------------------------


def _object_mask(ctx):
    """Pixels on the scene's objects (spheres, boxes, cylinders that are not walls)."""
    prim = ctx.geom["prim"]
    mask = np.zeros(prim.shape, bool)
    for i, p in enumerate(ctx.spec.prims):
        if isinstance(p, Sphere | Cylinder):
            mask |= prim == i
        elif isinstance(p, Box):
            size = np.asarray(p.hi, float) - np.asarray(p.lo, float)
            if size.min() > 0.02 and size.max() < 1.5:  # objects, not slabs of wall
                mask |= prim == i
    return mask


def mp_subsurface_objects(ctx, rng):
    """Subsurface scattering in translucent objects (wax, plastic, skin-like): a share beta =
    0.5-0.9 of an object's return travels inside the material before leaving it, its extra path
    exponentially distributed with mean l = 4-15 cm, so the return at harmonic n is multiplied by
    (1 - beta) + beta / (1 - i n omega l / c0): a delay (the object seen farther by about beta l /
    2) and a loss of amplitude, on the objects only. D. Freedman, Y. Smolin, E. Krupka, I.
    Leichter, M. Schmidt, "SRA: fast removal of general multipath for ToF sensors", ECCV 2014 (the
    backscattering profile, including subsurface scattering); M. Gupta, S. K. Nayar, M. B.
    Hullin, J. Martin, "Phasor imaging: a generalization of correlation-based time-of-flight
    imaging", ACM Trans. Graphics 34(5), 2015 (global light: interreflections and
    subsurface scattering as a temporally spread return)."""
    beta = rng.uniform(0.5, 0.9)
    ell = rng.uniform(0.04, 0.15)
    mask = _object_mask(ctx)
    w = 2 * np.pi * F_MOD

    def sig(c, ns):
        b = base_signal(c, ns)
        out = {}
        for n in ns:
            if n == 0:
                out[n] = b[n]
            else:
                f = (1 - beta) + beta / (1 - 1j * n * w * ell / C0)
                out[n] = np.where(mask, b[n] * f, b[n])
        return out

    return (
        Plan(signal=sig),
        ell,
        "m mean extra path in the material",
        {"beta": beta, "object_share": float(mask.mean()), "delay_m_approx": beta * ell / 2},
    )


def mp_translucent_sheet(ctx, rng):
    """A translucent sheet (a plastic strip curtain, a fogged protective screen) hanging across
    part of the view at z_s = 0.6-1.4 m: it backscatters diffusely (a Lambertian return of
    strength 0.1-0.4 x the direct return behind it, at the median, kept below the well) and
    passes tau^2 (tau = 0.6-0.9) of the light to the scene and back; each covered pixel sees two
    returns, the sheet's and the scene's, and reports a depth between them. A. Bhandari, A.
    Kadambi, R. Whyte, C. Barsi, M. Feigin, A. Dorrington, R. Raskar, "Resolving multipath
    interference in time-of-flight imaging via modulation frequency diversity and sparse
    regularization", Optics Letters 39(6), 2014 (two-return scenes through a semi-transparent
    layer); J. P. Godbaz, M. J. Cree, A. A. Dorrington, "Closed-form inverses for the mixed
    pixel/multipath interference problem in AMCW lidar", Proc. SPIE 8296, 2012 (the two-return
    model)."""
    zs = rng.uniform(0.6, 1.4)
    tau = rng.uniform(0.6, 0.9)
    ratio = rng.uniform(0.1, 0.4)
    frac = rng.uniform(0.3, 0.6)
    d = _rays(ctx.h, ctx.w, ctx.spec.pitch_deg)
    xs = np.arctan2(d[..., 0], d[..., 2])
    cut = np.quantile(xs, frac if rng.uniform() < 0.5 else 1 - frac)
    left = rng.uniform() < 0.5
    cover = (xs < cut) if left else (xs > cut)
    rs = zs / np.maximum(d[..., 2], 1e-6)  # the sheet is the plane z = z_s
    cover &= rs < ctx.geom["r"] - 0.05
    unit_s = d[..., 2] / rs**2  # cos of the incidence on the plane z = z_s / r^2
    e_direct = ctx.e_act
    rho_s = ratio * float(np.median(e_direct[cover])) / float(np.median(ctx.k_act * unit_s[cover]))
    e_s = np.where(cover, ctx.k_act * rho_s * unit_s, 0.0)
    cap = 0.5 * (0.6 * FULL_WELL) / (1 + MOD_CONTRAST)
    e_s = np.minimum(e_s, cap)
    ph_s = 4 * np.pi * F_MOD * rs / C0
    att = np.where(cover, tau * tau, 1.0)

    def sig(c, ns):
        b = base_signal(c, ns)
        return {n: b[n] * att + (e_s if n == 0 else e_s * np.exp(1j * n * ph_s)) for n in ns}

    return (
        Plan(signal=sig),
        ratio,
        "sheet return / direct return (median)",
        {"sheet_m": zs, "tau": tau, "rho_sheet": rho_s, "covered_share": float(cover.mean())},
    )


# ----------------------------------------------------------------------------------------------
# noise floor
# ----------------------------------------------------------------------------------------------


def nf_source_intensity_noise(ctx, rng):
    """Intensity noise of the light source between the sub-frames: each of the four sequential
    sub-frames of every frame gets its own emitted power (1 + s z_tk), z ~ N(0, 1), the same for
    all pixels (one source); the phase error (rms about s for m = 0.75) does not fall with the
    amplitude and depends on each pixel's phase; s = 2.5-5 x the per-frame phase noise at the
    median pixel. K. Petermann, "Laser Diode Modulation and Noise", Kluwer 1988 (relative
    intensity noise); R. Lange, PhD thesis, Univ. Siegen 2000 (the four samples taken
    one after the other)."""
    s = rng.uniform(2.5, 5.0) * float(np.median(noise_rad(ctx))) * math.sqrt(ctx.t)
    g = 1 + s * rng.standard_normal((ctx.t, N_PHASES, 1, 1))
    return (
        Plan(gain_active=g, temporal=True),
        s,
        "relative rms power per sub-frame",
        {"power_rms": s},
    )


def nf_row_clock_jitter(ctx, rng):
    """Row-wise clock jitter: the demodulation clock reaches each row through its own driver,
    whose timing jitters from frame to frame (Gaussian, the same along the row), so every frame
    has a random phase per row, independent of the amplitude; rms 2.5-5 x the per-frame phase
    noise at the median pixel. C. S. Bamji et al., IEEE JSSC 50(1), 2015 (the
    demodulation clock distributed over the array by drivers); one driver per row and its
    frame-to-frame jitter are this generator's assumptions from that layout."""
    sp = rng.uniform(2.5, 5.0) * float(np.median(noise_rad(ctx))) * math.sqrt(ctx.t)
    ph = sp * rng.standard_normal((ctx.t, 1, ctx.h, 1))
    return (
        Plan(phase=np.broadcast_to(ph, (ctx.t, 1, ctx.h, ctx.w)).copy(), temporal=True),
        sp,
        "rad rms per row and frame",
        {"depth_rms_m": sp * M_PER_RAD},
    )


HELDOUT2_FORMS = {
    "saturation": {
        "column_adc_clip": sat_column_adc_clip,
        "ambient_full_well": sat_ambient_full_well,
        "differential_clip": sat_differential_clip,
    },
    "fpn_pattern": {"ar_column_pixel": fpn_ar_column_pixel, "emi_fringe": fpn_emi_fringe},
    "amplitude_bias": {"bright_end": ab_bright_end, "inverse_power": ab_inverse_power},
    "cyclic_error": {
        "led_rc_pulse": ce_led_rc_pulse,
        "subframe_power_droop": ce_subframe_power_droop,
    },
    "pixel_gain": {"demod_contrast_map": pg_demod_contrast_map, "nir_fringing": pg_nir_fringing},
    "impulsive_pixels": {"stuck_taps": imp_stuck_taps, "adc_sparkle_codes": imp_adc_sparkle_codes},
    "vignetting": {"barrel_clip": vig_barrel_clip, "flat_top_diffuser": vig_flat_top_diffuser},
    "temporal_drift": {
        "phase_random_walk": td_phase_random_walk,
        "hotspot_overshoot": td_hotspot_overshoot,
    },
    "flying_pixels": {"defocus_disc": fp_defocus_disc, "pixel_crosstalk": fp_pixel_crosstalk},
    "multipath": {
        "subsurface_objects": mp_subsurface_objects,
        "translucent_sheet": mp_translucent_sheet,
    },
    "noise_floor": {
        "source_intensity_noise": nf_source_intensity_noise,
        "row_clock_jitter": nf_row_clock_jitter,
    },
}

SEED0 = 900_000  # the second held-out part's first seed (dev 0, held-out 500000)

__all__ = ["HELDOUT2_FORMS", "HELDOUT2_SCENES", "SEED0", "generate"]


def generate(family, form, seed, size=(120, 160, 24)):
    """A second-held-out recording (``family`` in HELDOUT2_FORMS or "none"/"null"), deterministic
    per seed."""
    return generate_with(HELDOUT2_FORMS, HELDOUT2_SCENES, family, form, seed, size, "heldout2")
