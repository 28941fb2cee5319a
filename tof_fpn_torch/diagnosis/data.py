"""What the diagnosis sees of a recording: checked frames, per-pixel statistics, the scene.

EMVA 1288 separates a sensor's temporal noise from its spatial non-uniformity by taking the
temporal mean and the temporal variance of every pixel. For independent Gaussian frames these two
are sufficient and independent: the frame-level log-likelihood of pixel ``p`` is
``log N(m_p; mu_p, sigma_p^2 / n_p) + [(n_p - 1) log-density of M2_p / sigma_p^2 ~ chi^2_{n_p-1}]``
(plus a constant), so the whole fit runs on ``(n, m, M2)`` per pixel and channel; the frames are
kept only for the effects that act per frame (drift, impulsive pixels) and the frame axis.

Where the modulation frequency is known, each pixel's frames are folded to within half an
unambiguous range of their temporal median before the statistics are taken (a frame that noise
pushes across the wrap is not an outlier); a pixel whose median itself is folded stays folded.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch
import torch.nn.functional as F

from .. import constants as K
from ..io import Recording, SceneData
from ..sim import Camera, Scene

__all__ = [
    "MIN_FRAME_SIDE",
    "Observations",
    "estimate_scene",
    "observe",
    "pixel_stats",
    "stated_clip_level",
]

#: The smallest frame side (px) the diagnosis takes: its split into fitting and held-out pixels
#: and its column and row statistics need a few pixels each way.
MIN_FRAME_SIDE: int = 8


@dataclass
class Observations:
    """A recording as the diagnosis uses it (float64 CPU; maps (H, W), frames (T, H, W)).

    ``depth``/``amplitude``: frames (NaN where invalid); ``valid``: frame-pixels with valid depth
    and finite amplitude; ``n, m_d, m2_d, m_a, m2_a``: per-pixel count, temporal mean and summed
    squared deviation of depth (m) and amplitude; ``scene_depth``, ``reflectance``, ``known``: the
    scene (``scene_estimated`` when it came from the recording); ``frequency`` (Hz, None:
    unknown), ``n_phases``, ``integration_time`` (s), ``times`` (T,) s, ``q_depth``/``q_amp``:
    quantisation steps of the stored values (0: none found); ``notes``: assumptions made;
    ``clip_level``: the largest raw sample the camera can record (its full well or top code, in
    the stored units) when the recording states it, else None; ``raw``: the correlation samples
    (T, N, H, W) when the recording has them, else None; ``simulator``: the recording states
    that the package's simulator made it (``meta["sim_camera"]``).
    """

    depth: torch.Tensor
    amplitude: torch.Tensor
    valid: torch.Tensor
    n: torch.Tensor
    m_d: torch.Tensor
    m2_d: torch.Tensor
    m_a: torch.Tensor
    m2_a: torch.Tensor
    scene_depth: torch.Tensor
    reflectance: torch.Tensor
    known: torch.Tensor
    scene_estimated: bool
    frequency: float | None
    n_phases: int
    integration_time: float
    times: torch.Tensor
    q_depth: float
    q_amp: float
    amplitude_unit: str = "DN"
    notes: list = field(default_factory=list)
    clip_level: float | None = None
    raw: torch.Tensor | None = None
    simulator: bool = False

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.m_d.shape)

    @property
    def frames(self) -> int:
        return self.depth.shape[0]

    def scene(self, dtype: torch.dtype = torch.float32) -> Scene:
        """The scene as a simulator :class:`~tof_fpn_torch.sim.Scene` (unknown pixels filled);
        float32 by default: the model's chain runs in single precision (the likelihood in
        double)."""
        d = torch.where(self.known, self.scene_depth, self.scene_depth[self.known].median())
        r = torch.where(self.known, self.reflectance, torch.full_like(d, 0.5))
        return Scene(d[None, None].to(dtype), r.clamp(1e-4, 1.0)[None, None].to(dtype))

    def camera(self) -> Camera:
        f = self.frequency if self.frequency is not None else K.CAMCUBE_MODULATION_FREQUENCY_HZ
        return Camera(
            modulation_frequency=f,
            n_phases=self.n_phases,
            integration_time=self.integration_time,
            adc_bits=32,
            full_well=1e30,
        )


def _quantum(x: torch.Tensor, steps: tuple[float, ...]) -> float:
    """The largest of ``steps`` that every value of ``x`` is a multiple of (0: none)."""
    if x.numel() == 0:
        return 0.0
    sample = x[:: max(1, x.numel() // 20000)]
    for q in sorted(steps, reverse=True):
        k = sample / q
        if bool(((k - k.round()).abs() < 0.02).all()):
            return q
    return 0.0


def pixel_stats(frames: torch.Tensor, valid: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """``(n, mean, M2)`` over the frames (T, H, W) where ``valid``."""
    if bool(valid.all()):  # the common case, in fewer passes (each one also in the backward)
        m = frames.mean(0)
        return torch.full_like(m, frames.shape[0]), m, ((frames - m) ** 2).sum(0)
    v = valid.to(frames.dtype)
    x = torch.where(valid, frames, torch.zeros_like(frames))
    n = v.sum(0)
    m = x.sum(0) / n.clamp_min(1)
    m2 = (v * (x - m) ** 2).sum(0)
    return n, m, m2


def fold(frames: torch.Tensor, valid: torch.Tensor, period: float | None) -> torch.Tensor:
    """Each pixel's frames moved by whole ``period`` s to within ``period / 2`` of its median."""
    if period is None or frames.shape[0] < 2:
        return frames
    med = torch.where(valid, frames, torch.full_like(frames, math.nan)).nanmedian(0).values
    d = frames - med
    return med + d - period * torch.round(d / period)


def _meta_number(meta: dict, key: str, lo: float, hi: float, what: str):
    v = meta.get(key)
    if v is None:
        return None
    if isinstance(v, (list, tuple)):
        return list(v)
    if not (lo <= float(v) <= hi):
        raise ValueError(f"recording meta[{key!r}] = {v!r} is out of range: {what}")
    return float(v)


def _settings(meta: dict) -> tuple:
    """``(modulation frequency or None, phases, integration time in s, notes)`` from the
    recording's meta (assumptions made are noted; a value out of range raises)."""
    notes = []
    f = _meta_number(meta, "modulation_frequency_hz", 1e5, 1e10, "expected 0.1 MHz .. 10 GHz")
    if isinstance(f, list):
        notes.append(
            f"several modulation frequencies {f}: the camera unwraps them itself; the diagnosis "
            "treats the frequency as unknown"
        )
        f = None
    if f is None:
        notes.append(
            "modulation frequency unknown: the correlation model assumes "
            f"{K.CAMCUBE_MODULATION_FREQUENCY_HZ / 1e6:g} MHz (cyclic-error period and wrapping "
            "are not checked against the camera's)"
        )
    n_ph = meta.get("n_phases")
    if n_ph is None:
        n_ph = 4
        notes.append("number of phases unknown: N = 4 assumed")
    elif n_ph < 4:
        raise ValueError(
            f"recording meta['n_phases'] = {n_ph} is out of range: the correlation model "
            "needs N >= 4 samples per frame"
        )
    ti = _meta_number(meta, "integration_time_us", 1e-3, 1e6, "expected 1 ns .. 1 s")
    ti = 1e-3 if ti is None else ti * 1e-6
    return f, n_ph, ti, notes


def stated_clip_level(meta: dict) -> float | None:
    """The largest raw sample (stored units) the recording's camera can record, when its meta
    states it: ``full_well_dn``, or the full well and ADC of ``sim_camera`` (what
    ``io.recording_from_simulation`` writes): ``min(round(full_well / conversion_gain),
    2**adc_bits - 1)``. None otherwise."""
    lv = meta.get("full_well_dn")
    if lv is None:
        cam = meta.get("sim_camera")
        if not isinstance(cam, dict) or "full_well" not in cam or "conversion_gain" not in cam:
            return None
        try:
            lv = round(float(cam["full_well"]) / float(cam["conversion_gain"]))
            if "adc_bits" in cam:
                lv = min(lv, 2 ** int(cam["adc_bits"]) - 1)
        except (TypeError, ValueError, OverflowError):
            return None
    lv = float(lv)
    if not (math.isfinite(lv) and lv > 0):
        raise ValueError(f"recording meta states a clip level of {lv!r}: expected a number > 0")
    return lv


def observe(recording: Recording, scene=None) -> Observations:
    """Check ``recording`` (and ``scene``) and compute what the diagnosis needs.

    Raises ``ValueError`` naming the problem: not a recording, frames without a valid pixel,
    meta out of range, a scene of another size or with no known pixel.
    """
    if not isinstance(recording, Recording):
        raise ValueError(f"recording must be a tof_fpn_torch.io.Recording, got {type(recording)}")
    depth = recording.depth[:, 0].to(torch.float64)
    amp = recording.amplitude[:, 0].to(torch.float64)
    t, h, w = depth.shape
    if h < MIN_FRAME_SIDE or w < MIN_FRAME_SIDE:
        m = MIN_FRAME_SIDE
        raise ValueError(
            f"recording frames are {h}x{w}; the diagnosis needs at least {m}x{m} pixels"
        )
    valid = torch.isfinite(depth) & (depth > 0) & torch.isfinite(amp) & (amp >= 0)
    empty = [i for i in range(t) if not bool(valid[i].any())]
    if len(empty) == t:
        raise ValueError(f"recording has no valid pixel in any of its {t} frame(s)")
    if empty:
        raise ValueError(f"recording frames {empty} have no valid pixel (depth NaN everywhere)")
    f, n_ph, ti, notes = _settings(recording.meta)
    ts = recording.timestamps_s
    times = ts.to(torch.float64) - ts[0] if ts is not None else torch.arange(t, dtype=torch.float64)
    if ts is None and t > 1:
        notes.append("no timestamps: time is counted in frames")
    if bool((~torch.isfinite(amp) & torch.isfinite(depth)).any()):
        notes.append("some pixels have valid depth but no amplitude: left out")
    period = None if f is None else K.SPEED_OF_LIGHT_AIR / (2.0 * f)
    depth = torch.where(valid, depth, torch.full_like(depth, math.nan))
    folded = fold(depth, valid, period)
    n, m_d, m2_d = pixel_stats(folded, valid)
    _, m_a, m2_a = pixel_stats(amp, valid)
    q_d = _quantum(depth[valid], (1e-3, 1e-4))
    q_a = _quantum(amp[valid], (1.0,))
    obs = Observations(
        depth=torch.where(valid, folded, torch.full_like(depth, math.nan)),
        amplitude=torch.where(valid, amp, torch.full_like(amp, math.nan)),
        valid=valid,
        n=n,
        m_d=m_d,
        m2_d=m2_d,
        m_a=m_a,
        m2_a=m2_a,
        scene_depth=torch.zeros(h, w, dtype=torch.float64),
        reflectance=torch.zeros(h, w, dtype=torch.float64),
        known=torch.zeros(h, w, dtype=torch.bool),
        scene_estimated=scene is None,
        frequency=f,
        n_phases=int(n_ph),
        integration_time=ti,
        times=times,
        q_depth=q_d,
        q_amp=q_a,
        amplitude_unit=str(recording.meta.get("amplitude_unit", "camera units")),
        notes=notes,
        clip_level=stated_clip_level(recording.meta),
        simulator=isinstance(recording.meta.get("sim_camera"), dict),
        raw=None if recording.raw is None else recording.raw.to(torch.float64),
    )
    if scene is None:
        d, r, known = estimate_scene(obs)
        notes.append(
            "scene estimated from the recording (temporal median, edge-aware smoothing over "
            f"{2 * _RADIUS + 1}x{2 * _RADIUS + 1} px): structure finer than that (stripes, pixel "
            "defects, noise law, per-frame changes) can be seen; anything smooth (vignetting, "
            "amplitude bias, cyclic error, saturation of broad areas) is absorbed into the "
            "estimated scene and cannot"
        )
    else:
        d, r, known = _scene_maps(scene, h, w)
    obs.scene_depth, obs.reflectance, obs.known = d, r, known & (n > 0)
    if not bool(obs.known.any()):
        raise ValueError("no pixel has both a known scene and valid data")
    return obs


def _scene_maps(scene, h: int, w: int):
    if isinstance(scene, SceneData):
        d, r = scene.depth[0, 0], scene.reflectance[0, 0]
        known = scene.mask[0, 0] if scene.mask is not None else torch.ones_like(d, dtype=bool)
    elif isinstance(scene, Scene):
        if scene.depth.shape[0] != 1:
            raise ValueError(f"scene must hold one scene, got a batch of {scene.depth.shape[0]}")
        d, r = scene.depth[0, 0], scene.reflectance[0, 0]
        known = torch.ones_like(d, dtype=torch.bool)
    else:
        raise ValueError(f"scene must be a SceneData or sim.Scene, got {type(scene).__name__}")
    if tuple(d.shape) != (h, w):
        raise ValueError(
            f"scene is {d.shape[0]}x{d.shape[1]} pixels, the recording {h}x{w}: they must match"
        )
    d = d.to(torch.float64)
    r = r.to(torch.float64)
    known = known & torch.isfinite(d) & (d > 0) & torch.isfinite(r) & (r > 0)
    return (
        torch.where(known, d, torch.ones_like(d)),
        torch.where(known, r, torch.ones_like(r)),
        known,
    )


_RADIUS = 3


def _bilateral(x: torch.Tensor, guide: torch.Tensor, wgt: torch.Tensor, h_range: torch.Tensor):
    r = _RADIUS
    k = 2 * r + 1
    pad = (r, r, r, r)
    xs = F.unfold(F.pad(x[None, None], pad, mode="replicate"), k)[0]
    gs = F.unfold(F.pad(guide[None, None], pad, mode="replicate"), k)[0]
    ws = F.unfold(F.pad(wgt[None, None], pad, mode="constant"), k)[0]
    yy, xx = torch.meshgrid(torch.arange(-r, r + 1.0), torch.arange(-r, r + 1.0), indexing="ij")
    spatial = torch.exp(-(yy**2 + xx**2) / (2 * 2.0**2)).reshape(-1, 1).to(x.dtype)
    g0 = guide.reshape(1, -1)
    rng = torch.exp(-0.5 * ((gs - g0) / h_range.reshape(1, -1)) ** 2)
    wt = spatial * rng * ws
    return ((wt * xs).sum(0) / wt.sum(0).clamp_min(1e-12)).reshape(x.shape)


def estimate_scene(obs: Observations):
    """Depth, reflectance and known-mask of the scene from the recording itself.

    Temporal median of every pixel (robust to single bad frames), then two passes of an
    edge-aware (bilateral) smoothing over 7x7 px guided by the depth with a range scale of three
    times the local noise; the reflectance is the smoothed amplitude times depth squared (the
    inverse-square law), scaled so that its 99.5th percentile is 1 (the fitted responsivity takes
    the scale). What this can reveal is discussed in docs/diagnosis.md.
    """
    v = obs.valid
    med_d = torch.where(v, obs.depth, torch.full_like(obs.depth, math.nan)).nanmedian(0).values
    med_a = torch.where(v, obs.amplitude, torch.full_like(obs.depth, math.nan)).nanmedian(0).values
    known = torch.isfinite(med_d) & (v.to(torch.float64).mean(0) >= 0.5)
    fill_d = med_d[known].median()
    d = torch.where(known, med_d, fill_d)
    a = torch.where(known, med_a, med_a[known].median()).clamp_min(0)
    # local noise of the depth: robust scale of a 3x3 high-pass, smoothed
    hp = d - F.avg_pool2d(F.pad(d[None, None], (1, 1, 1, 1), mode="replicate"), 3, 1)[0, 0]
    sig = K.MAD_TO_SIGMA * hp.abs()
    sig = F.avg_pool2d(F.pad(sig[None, None], (3, 3, 3, 3), mode="replicate"), 7, 1)[0, 0]
    floor = max(float(sig[known].median()), 1e-4)
    h_range = 3.0 * sig.clamp_min(floor) + (obs.q_depth or 0.0)
    wgt = known.to(d.dtype)
    for _ in range(2):
        d_new = _bilateral(d, d, wgt, h_range)
        a = _bilateral(a, d, wgt, h_range)
        d = d_new
    rho = a * d * d
    top = float(torch.quantile(rho[known], 0.995))
    rho = (rho / max(top, 1e-12)).clamp(1e-4, 1.0)
    return d, rho, known
