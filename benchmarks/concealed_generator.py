"""A ToF recording generator richer than the diagnosing model, written apart from it (NumPy only).

Nothing here imports the simulator or the diagnosis: the physics is written again, with other
formulas and parametrisations, so that passing the concealed-effect benchmark is not circular.
The diagnosis only ever sees the recording (depth, amplitude, meta) and the scene.

Base physics (always on; the diagnosing baseline's family):
    electrons of sample n:  q_n = bg rho + S (1 + c corr(phi + 2 pi n / N)) + o_n(x),
    S = k_sig rho / d^2,  phi = 4 pi f d / c_air,  corr = cos,
    o_n(x) = [a1 cos(2 pi x / 3 + t1) + a2 cos(pi x)] cos(2 pi n / N - psi)   (column read-out FPN),
    exact Poisson shot noise, Gaussian read noise, conversion to DN, rounding, 16-bit ADC,
    decoding by the first DFT bin.

Concealed effects (one at a time; ``magnitude`` in the unit given):
    cyclic_error      light is a blend of a sine and a square wave, the reference a square wave:
                      the correlation (computed numerically) has odd harmonics; magnitude = the
                      share s of square wave in [0, 1]; truth: peak-to-peak depth error (mm)
    amplitude_bias    depth + beta * ln(1 + A_half / A) (A in e-), magnitude beta (mm)
    fpn_pattern       clock skew: a detrended random walk plus white jitter along the columns
                      (or the rows), a phase delay; magnitude: rms (mm)
    vignetting        cos^4 law about an off-centre optical axis, focal length chosen so that the
                      corner loses ``magnitude`` (fraction) of the light
    temporal_drift    linear warm-up: delay grows by ``magnitude`` (mm) over the recording
    noise_floor       clock jitter: Gaussian delay per pixel and frame, rms ``magnitude`` (mm)
    pixel_gain        log-normal quantum efficiency per pixel, rms ``magnitude`` (fraction)
    impulsive_pixels  random-telegraph pixels: a share ``magnitude`` of pixels, each frame with
                      probability 1/2 returning uniform random codes
    saturation        full well at the level that the brightest share ``magnitude`` of pixels
                      exceed (hard clip of every sample)
    flying_pixels     optical crosstalk: every 4-neighbour adds ``magnitude`` of its light
                      (phasor mixing at depth edges)
    phase_wrapping    modulation frequency raised so that a share ``magnitude`` of the scene lies
                      beyond the unambiguous range (the meta states the true frequency); truth
                      also how far beyond (median), the wrapped pixels' depth noise and SNR
    multipath         diffuse interreflection with the scene's geometry: pinhole camera (60 deg
                      horizontal field), every point q of a coarse grid (every 4th pixel) sends
                      the light it reflects (S_q d_q^2) to every point p with a softened inverse
                      square 1 / (|P_q - P_p|^2 + (1 m)^2), over the path d_q + |P_q - P_p| + d_p
                      (direct: 2 d_p); p returns it with its albedo. magnitude = median over the
                      pixels of relayed / direct active light; truth also the light-weighted mean
                      extra path (m)
"""

from __future__ import annotations

import math

import numpy as np

C_AIR = 299792458.0 / 1.000293
EFFECTS = (
    "cyclic_error",
    "amplitude_bias",
    "fpn_pattern",
    "vignetting",
    "temporal_drift",
    "noise_floor",
    "pixel_gain",
    "impulsive_pixels",
    "saturation",
    "flying_pixels",
    "phase_wrapping",
    "multipath",
)
RELAY_STEP = 4  # px between the relaying points
RELAY_SOFT_M = 1.0  # softening length of the inverse square (m)
FIELD_OF_VIEW_DEG = 60.0  # horizontal


CORRELATION_SAMPLES = 1 << 16  # table of the correlation waveform, read by linear interpolation


def _correlation(square_share: float, samples: int = CORRELATION_SAMPLES) -> np.ndarray:
    """Normalised correlation of the light (sine blended with a square wave) with a square
    reference, on ``samples`` phases in [0, 2 pi): zero mean, first harmonic of amplitude 1."""
    t = np.arange(samples) * 2 * np.pi / samples
    light = (1 - square_share) * np.cos(t) + square_share * np.sign(np.cos(t))
    ref = np.sign(np.cos(t))
    corr = np.real(np.fft.ifft(np.fft.fft(light) * np.conj(np.fft.fft(ref)))) / samples
    corr -= corr.mean()
    first = 2 * abs(np.fft.fft(corr)[1]) / samples
    return corr / first


def _wave(corr: np.ndarray, arg: np.ndarray) -> np.ndarray:
    """The correlation at phases ``arg`` (radians), linearly interpolated in its periodic table.

    Runs 1-7 took the nearest of 1024 table entries: that quantised every pixel's phase to
    2 pi / 1024, a depth staircase of 7.3 mm steps (+-3.7 mm, larger than the cyclic error at
    the detection magnitude) that only the cyclic-error recordings had -- a generator artefact,
    not physics. Interpolated in 65 536 entries the error is below 0.1 mm."""
    m = corr.size
    grid = np.arange(m) * (2 * np.pi / m)
    return np.interp(np.mod(arg, 2 * np.pi), grid, corr, period=2 * np.pi)


def _decode(q: np.ndarray, f: float):
    n = q.shape[1]
    th = 2 * np.pi * np.arange(n) / n
    re = np.tensordot(np.cos(th), q, axes=(0, 1))
    im = -np.tensordot(np.sin(th), q, axes=(0, 1))
    phase = np.mod(np.arctan2(im, re), 2 * np.pi)
    return phase * C_AIR / (4 * np.pi * f), 2.0 / n * np.hypot(re, im)


def _cyclic_truth(square_share: float, f: float, n: int = 4) -> float:
    corr = _correlation(square_share)
    phi = np.linspace(0, 2 * np.pi, 256, endpoint=False)
    q = _wave(corr, phi[:, None] + 2 * np.pi * np.arange(n)[None] / n).T[None]  # (1, N, 256)
    d, _ = _decode(q.reshape(1, n, 1, 256), f)
    err = d[0, 0] - phi * C_AIR / (4 * np.pi * f)
    r = C_AIR / (2 * f)
    err = (err + r / 2) % r - r / 2
    return float(err.max() - err.min())


def _relay(d: np.ndarray, rho: np.ndarray, sig: np.ndarray, f: float):
    """Relayed active light at every pixel (unnormalised): offset (H, W), complex modulated
    part (H, W) with the phase of its path, and the light-weighted mean extra path (m)."""
    h, w = d.shape
    fx = (w / 2) / math.tan(math.radians(FIELD_OF_VIEW_DEG / 2))
    yy, xx = np.mgrid[0:h, 0:w]
    ray = np.stack([(xx - (w - 1) / 2) / fx, (yy - (h - 1) / 2) / fx, np.ones((h, w))], -1)
    pts = d[..., None] * ray / np.linalg.norm(ray, axis=-1, keepdims=True)  # (H, W, 3), m
    sub = (slice(RELAY_STEP // 2, None, RELAY_STEP),) * 2
    pq, dq = pts[sub].reshape(-1, 3), d[sub].reshape(-1)
    sent = (sig * d**2)[sub].reshape(-1)  # light each relaying point reflects (any unit)
    k = 2 * np.pi * f / C_AIR  # phase per metre of path
    dc = np.zeros(h * w)
    z = np.zeros(h * w, dtype=np.complex128)
    extra_num = 0.0
    pp, dp = pts.reshape(-1, 3), d.reshape(-1)
    for i0 in range(0, h * w, 4096):
        sl = slice(i0, i0 + 4096)
        r = np.linalg.norm(pp[sl, None] - pq[None], axis=-1)  # (P, Q)
        wt = sent[None] / (r**2 + RELAY_SOFT_M**2)
        path = dq[None] + r + dp[sl, None]
        dc[sl] = wt.sum(1)
        z[sl] = (wt * np.exp(1j * k * path)).sum(1)
        extra_num += float((wt * (path - 2 * dp[sl, None])).sum())
    extra = extra_num / float(dc.sum())
    return dc.reshape(h, w) * rho, z.reshape(h, w) * rho, extra


def generate(
    depth,
    reflectance,
    *,
    frames=24,
    seed=0,
    effect=None,
    magnitude=0.0,
    frequency=20e6,
    n_phases=4,
    k_sig=3.0e4,
    bg=400.0,
    contrast=0.5,
    gain=25.0,
    read_e=10.0,
    fpn=(20.0, 15.0),
    psi=0.8,
):
    """One recording. ``depth`` (m), ``reflectance`` (H, W) arrays. Returns ``(depth_frames,
    amplitude_frames, meta, truth)``: (T, H, W) float32 (NaN invalid), the recording meta dict
    and what was planted (``truth["effect"]`` is None for a null recording)."""
    rng = np.random.default_rng(seed)
    d = np.asarray(depth, dtype=np.float64)
    rho = np.asarray(reflectance, dtype=np.float64)
    h, w = d.shape
    n = n_phases
    truth = {"effect": effect, "magnitude": magnitude}
    f = frequency
    if effect == "phase_wrapping":
        # raise f until the requested share of pixels lies beyond the range
        target = np.quantile(d, 1.0 - magnitude)
        f = C_AIR / (2 * target)
        truth["range_m"] = C_AIR / (2 * f)
        truth["share_beyond"] = float((d >= truth["range_m"]).mean())
    sig = k_sig * rho / d**2  # e- of the modulated light per sample (before contrast)
    amb = bg * rho
    if effect == "phase_wrapping":
        # how far the wrapped pixels lie beyond the range, against their own depth noise (what
        # decides whether a wrap can be seen: a reading within its noise of 0 / R is either)
        beyond = d >= truth["range_m"]
        a_e = contrast * sig[beyond]
        s_e = np.sqrt(2 * (amb[beyond] + sig[beyond] + read_e**2 + gain**2 / 12) / n)
        sd_d = C_AIR / (4 * np.pi * f) * s_e / a_e
        excess = d[beyond] - truth["range_m"]
        truth["beyond_excess_m_median"] = float(np.median(excess))
        truth["beyond_depth_sd_m_median"] = float(np.median(sd_d))
        # pixels that read on the near side of 0 in >= 98 % of the frames
        truth["pixels_beyond_by_2_sd"] = int((excess >= 2 * sd_d).sum())
        truth["beyond_snr_median"] = float(np.median(a_e / s_e))
    if effect == "vignetting":
        cx, cy = rng.uniform(-0.05, 0.05) * w, rng.uniform(-0.05, 0.05) * h
        corner = max(
            math.hypot(x - cx, y - cy)
            for x in (-(w - 1) / 2, (w - 1) / 2)
            for y in (-(h - 1) / 2, (h - 1) / 2)
        )
        # cos^4(atan(r / fl)) = (1 + (r / fl)^2)^-2 = 1 - magnitude at the far corner
        fl = corner / math.sqrt((1 - magnitude) ** -0.5 - 1)
        yy, xx = np.mgrid[0:h, 0:w]
        r = np.hypot(xx - (w - 1) / 2 - cx, yy - (h - 1) / 2 - cy)
        v = (1 + (r / fl) ** 2) ** -2
        sig, amb = sig * v, amb * v
        truth["corner_loss"] = magnitude
    if effect == "pixel_gain":
        qe = np.exp(magnitude * rng.standard_normal((h, w)) - magnitude**2 / 2)
        sig, amb = sig * qe, amb * qe
        truth["rms"] = float(qe.std())
    phi = 4 * np.pi * f * d / C_AIR
    delay = np.zeros((frames, h, w))
    if effect == "amplitude_bias":
        a_e = sig * contrast
        a_half = np.median(a_e)
        bias = magnitude * 1e-3 * np.log1p(a_half / a_e)
        delay += bias[None]
        truth["bias_p10_minus_p90_mm"] = float(
            (np.quantile(bias, 0.9) - np.quantile(bias, 0.1)) * 1e3
        )
    if effect == "fpn_pattern":
        axis_len = w if seed % 2 == 0 else h
        walk = np.cumsum(rng.standard_normal(axis_len))
        walk -= np.polyval(np.polyfit(np.arange(axis_len), walk, 1), np.arange(axis_len))
        prof = walk / walk.std() + 1.5 * rng.standard_normal(axis_len)
        prof = prof / prof.std() * magnitude * 1e-3
        delay += prof[None, None, :] if axis_len == w and seed % 2 == 0 else prof[None, :, None]
        truth["orientation"] = "columns" if seed % 2 == 0 else "rows"
        truth["rms_mm"] = magnitude
    if effect == "temporal_drift":
        delay += (np.arange(frames) / max(frames - 1, 1) * magnitude * 1e-3)[:, None, None]
        truth["total_mm"] = magnitude
    if effect == "noise_floor":
        delay += rng.standard_normal((frames, h, w)) * magnitude * 1e-3
        truth["sigma_mm"] = magnitude
    phase = phi[None] + 4 * np.pi * f * delay / C_AIR  # (T, H, W)
    th = 2 * np.pi * np.arange(n) / n
    arg = phase[:, None] + th[None, :, None, None]  # (T, N, H, W)
    if effect == "cyclic_error":
        wave = _wave(_correlation(magnitude), arg)
        truth["peak_to_peak_mm"] = _cyclic_truth(magnitude, f, n) * 1e3
    else:
        wave = np.cos(arg)
    q = amb[None, None] + sig[None, None] * (1 + contrast * wave)
    if effect == "multipath":
        dc, z, extra = _relay(d, rho, sig, f)
        scale = magnitude / np.median(dc / sig)
        dc, z = dc * scale, z * scale
        # the relayed light: offset dc, modulated part contrast |z| at the phase of z
        q = (
            q
            + dc[None, None]
            + contrast * np.real(z[None, None] * np.exp(1j * th)[None, :, None, None])
        )
        truth["relay_share"] = magnitude
        truth["mean_extra_path_m"] = extra
    if effect == "flying_pixels":
        # every 4-neighbour leaks `magnitude` of its light (correlation samples add linearly)
        qp = np.pad(q, ((0, 0), (0, 0), (1, 1), (1, 1)), mode="edge")
        q = (1 - 4 * magnitude) * q + magnitude * (
            qp[..., :-2, 1:-1] + qp[..., 2:, 1:-1] + qp[..., 1:-1, :-2] + qp[..., 1:-1, 2:]
        )
        truth["crosstalk"] = magnitude
    x = np.arange(w)
    t1 = rng.uniform(0, 2 * np.pi)
    pat = fpn[0] * np.cos(2 * np.pi * x / 3 + t1) + fpn[1] * np.cos(np.pi * x)
    q = q + pat[None, None, None, :] * np.cos(th - psi)[None, :, None, None]
    q = rng.poisson(np.clip(q, 0, None)).astype(np.float64)
    q += rng.normal(0.0, read_e, q.shape)
    if effect == "saturation":
        peak = q.max(axis=1)  # (T, H, W)
        well = float(np.quantile(peak[0], 1.0 - magnitude))
        q = np.minimum(q, well)
        truth["share_clipped"] = magnitude
        truth["full_well_e"] = well
    dn = np.clip(np.round(q / gain), 0, 65535)
    if effect == "impulsive_pixels":
        bad = rng.random((h, w)) < magnitude
        flick = (rng.random((frames, h, w)) < 0.5) & bad[None]
        rand = rng.integers(0, 2000, size=dn.shape).astype(np.float64)
        dn = np.where(flick[:, None], rand, dn)
        truth["share_frame_pixels"] = float(flick.mean())
    depth_f, amp = _decode(dn, f)
    depth_f = np.where(depth_f > 0, depth_f, np.nan).astype(np.float32)
    meta = {
        "modulation_frequency_hz": f,
        "integration_time_us": 300.0,
        "n_phases": n,
        "amplitude_unit": "DN",
        "source": "benchmarks/concealed_generator.py",
    }
    return depth_f, amp.astype(np.float32), meta, truth
