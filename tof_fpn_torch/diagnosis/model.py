"""The diagnosing model: a simulator chain whose noise-free output is the mean, plus the noise law.

Baseline (issue 10): ideal sinusoidal correlation (:class:`~tof_fpn_torch.sim.Photons`, amplitude
``k rho / d^2`` up to the camera constants, ``k`` = ``photons.responsivity`` fitted), offset ``B``
(active light over the demodulation contrast plus ambient), photon shot and read noise (the
conversion gain ``g`` and the read noise fitted), column read-out FPN at ``2 pi / 3`` and ``pi``
(:class:`~tof_fpn_torch.sim.ReadoutFPN`'s offsets ``o_n(x) = p(x) cos(2 pi n / N - psi)``; the
three signed amplitudes of ``p`` and ``psi`` fitted). No saturation, no wrapping.

Prediction for every pixel: the deterministic terms run on the scene (no noise), the samples are
divided by ``g`` (DN) and decoded by eq. (1): ``A_0``, ``B`` and the depth, which is unwrapped
around the scene depth unless ``phase_wrapping`` is in the model. The noise of one sample is
``v = B / g + (sigma_read / g)^2 + 1/12`` DN^2, so each component of ``X_1 (2/N)`` has standard
deviation ``s = sqrt(2 v / N)``: the amplitude is Rician (mean and spread from ``A_0`` and ``s``),
the depth Gaussian with ``sigma_D = (c_L / 4 pi f) s / A_0`` (eq. 2), plus the jitter of
``noise_floor`` and the quantisation of the stored values (``q^2 / 12``).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field, replace

import torch

from .. import constants as K
from ..sim import (
    ADC,
    STAGE,
    Camera,
    Photons,
    ReadNoise,
    ReadoutFPN,
    ShotNoise,
    SimState,
    Simulation,
    depth_from_samples,
)
from .catalogue import CATALOGUE, build_term
from .params import ParamSpec

__all__ = ["CORE_SPECS", "DiagnosisModel", "Prediction", "peak_samples", "predict"]

#: always fitted
CORE_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("photons.responsivity", "log", 1.0),
    ParamSpec("camera.conversion_gain", "log", 1.0, "e-/DN"),
    ParamSpec("camera.read_noise", "rootabs", 1.0, "e-"),
    ParamSpec("camera.ambient_irradiance", "abs", 0.1, "W/m^2"),
    ParamSpec("readout_fpn.cos_2pi3", "lin", 1.0, "e-"),
    ParamSpec("readout_fpn.sin_2pi3", "lin", 1.0, "e-"),
    ParamSpec("readout_fpn.cos_pi", "lin", 1.0, "e-"),
    ParamSpec("readout_fpn.sample_phase", "lin", 1.0, "rad"),
)
_TERM_OF = {n: (e.term or n) for n, e in CATALOGUE.items()}


@dataclass
class DiagnosisModel:
    """Camera, fitted values (``"owner.field"`` -> float), the catalogue effects in the model
    (in the order they were added) and the closed-form profiles (``"columns"``, ``"rows"``)."""

    camera: Camera
    values: dict
    effects: list = field(default_factory=list)
    profiles: dict = field(default_factory=dict)
    frame_interval: float = 1.0
    impulsive_level: float = 1e-6
    fpn_scale: float = 1.0

    def copy(self) -> DiagnosisModel:
        return DiagnosisModel(
            replace(self.camera),
            dict(self.values),
            list(self.effects),
            {k: v.clone() for k, v in self.profiles.items()},
            self.frame_interval,
            self.impulsive_level,
            self.fpn_scale,
        )

    def specs(self) -> list[ParamSpec]:
        """Every fitted scalar of the model (core + its effects)."""
        out = []
        for s in CORE_SPECS:
            if s.key.startswith(("readout_fpn.cos", "readout_fpn.sin")):
                s = replace(s, scale=self.fpn_scale)
            elif s.key == "camera.read_noise":
                s = replace(s, scale=self.fpn_scale**2)
            out.append(s)
        for e in self.effects:
            out.extend(CATALOGUE[e].specs)
        return out

    def n_parameters(self) -> float:
        """Number of fitted parameters (closed-form profiles count their effective degrees of
        freedom, stored in ``values["fpn_pattern.dof"]``)."""
        return len(self.specs()) + float(self.values.get("fpn_pattern.dof", 0.0))

    def with_effect(self, name: str, init: dict) -> DiagnosisModel:
        m = self.copy()
        if name not in m.effects:
            m.effects.append(name)
        m.values.update(init)
        return m

    def without(self, name: str) -> DiagnosisModel:
        """A copy without effect ``name`` (its values and profiles dropped)."""
        m = self.copy()
        if name in m.effects:
            m.effects.remove(name)
        m.values = {k: v for k, v in m.values.items() if not k.startswith(name + ".")}
        if name == "fpn_pattern":
            m.profiles = {}
        return m

    def readout_fpn(self) -> ReadoutFPN:
        """The baseline FPN as the simulator's :class:`ReadoutFPN` (amplitude >= 0, phases)."""
        v = self.values
        a2 = math.hypot(v["readout_fpn.cos_2pi3"], v["readout_fpn.sin_2pi3"])
        th2 = math.atan2(v["readout_fpn.sin_2pi3"], v["readout_fpn.cos_2pi3"])
        cpi = v["readout_fpn.cos_pi"]
        return ReadoutFPN(
            frequencies=K.FPN_FREQUENCIES,
            offset_amplitudes=(a2, abs(cpi)),
            gain_amplitudes=(0.0, 0.0),
            spatial_phases=(th2, 0.0 if cpi >= 0 else math.pi),
            sample_phase=v["readout_fpn.sample_phase"],
            random_offset=0.0,
            random_gain=0.0,
        )

    def simulation_camera(self) -> Camera:
        f = float(self.camera.modulation_frequency)
        if "phase_wrapping" in self.effects:
            f = K.SPEED_OF_LIGHT_AIR / (2.0 * self.values["phase_wrapping.range"])
        return replace(
            self.camera,
            full_well=1e30,  # the model has no saturation unless `saturation` is in it
            adc_bits=32,
            modulation_frequency=f,
            conversion_gain=self.values["camera.conversion_gain"],
            read_noise=self.values["camera.read_noise"],
            ambient_irradiance=self.values.get("camera.ambient_irradiance", 0.1),
        )

    def simulation(self) -> Simulation:
        """The model as a complete, noisy :class:`~tof_fpn_torch.sim.Simulation` (DN out)."""
        v = self.values
        terms = [Photons(responsivity=v["photons.responsivity"]), ShotNoise(), self.readout_fpn()]
        terms += [ReadNoise(), ADC(quantize=True)]
        for e in self.effects:
            t = build_term(e, v, self, for_chain=False)
            if t is not None:
                terms.append(t)
        terms.sort(key=lambda t: STAGE.get(t.name, 50))
        return Simulation(self.simulation_camera(), terms)


@dataclass
class Prediction:
    """Per-pixel (H, W) model predictions (float64): depth mean / sd per frame, amplitude mean /
    sd per frame (Rician), ``tau_a`` (sd of the pixel-gain random effect on the amplitude mean),
    the noise-free amplitude ``a0`` and offset ``offset`` (DN), ``s`` (sd of one component of
    ``(2/N) X_1``), ``wrap`` (R when the model folds the depth, else None)."""

    mu_d: torch.Tensor
    sd_d: torch.Tensor
    mu_a: torch.Tensor
    sd_a: torch.Tensor
    tau_a: torch.Tensor | float
    a0: torch.Tensor
    offset: torch.Tensor
    s: torch.Tensor
    wrap: object = None


def _rician(a0: torch.Tensor, s: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean and sd of ``|a0 + s (xi_1 + j xi_2)|``."""
    x = a0 * a0 / (4.0 * s * s)
    lag = (1 + 2 * x) * torch.special.i0e(x) + 2 * x * torch.special.i1e(x)
    mean = s * math.sqrt(math.pi / 2) * lag
    var = (a0 * a0 + 2 * s * s - mean * mean).clamp_min(1e-3 * s * s)
    return mean, torch.sqrt(var)


def _baseline_fpn(samples: torch.Tensor, v: dict) -> torch.Tensor:
    n, w = samples.shape[1], samples.shape[3]
    x = torch.arange(w, dtype=torch.float64)
    w23 = K.FPN_FREQUENCIES[0]
    dt = samples.dtype
    p = (
        v["readout_fpn.cos_2pi3"] * torch.cos(w23 * x).to(dt)
        - v["readout_fpn.sin_2pi3"] * torch.sin(w23 * x).to(dt)
        + v["readout_fpn.cos_pi"] * torch.cos(math.pi * x).to(dt)
    )
    th = torch.arange(n, dtype=torch.float64) * (2 * math.pi / n)
    wn = torch.cos(th - v["readout_fpn.sample_phase"])
    return samples + (wn.view(1, n, 1, 1) * p.view(1, 1, 1, w)).to(samples.dtype)


_PHOTONS_CACHE: dict = {}
_RELAY_CACHE: dict = {}


def _multipath(t, state, units, key, amb_irr, resp):
    """``t.apply(state)`` when ``state.samples`` are still the photons' ``(act + amb_irr amb)
    resp``: the scene relay is linear in the samples, so the relays of the two cached unit
    images are computed once per scene and geometry and scaled (the (sources x pixels) products
    and their backward pass ran in every prediction: a third of a diagnosis with multipath)."""
    if isinstance(t.scene_relay, (int, float)) and t.scene_relay == 0:
        return t.apply(state)
    rkey = (key, float(t.field_of_view), float(t.near_field), int(t.relay_step))
    rel = _RELAY_CACHE.get(rkey)
    if rel is None:
        with torch.no_grad():
            rel = (t.relayed(units[0], state), t.relayed(units[1], state))
        if len(_RELAY_CACHE) >= K.DIAG_RELAY_CACHE_SIZE:
            _RELAY_CACHE.clear()
        _RELAY_CACHE[rkey] = rel
    state = replace(t, scene_relay=0.0).apply(state)  # the uniform relay from outside the view
    state.samples = state.samples + t.scene_relay * resp * (rel[0] + rel[1] * amb_irr)
    return state


def predict(model: DiagnosisModel, obs, v: dict | None = None, scene=None) -> Prediction:
    """Model predictions for ``obs`` with values ``v`` (default ``model.values``; tensors keep
    the graph). ``scene``: a cached :class:`~tof_fpn_torch.sim.Scene` (default ``obs.scene()``)."""
    v = model.values if v is None else v
    scene = obs.scene() if scene is None else scene
    cam = model.camera
    # the photo-charge is linear in the responsivity and in the ambient irradiance: the
    # unit-responsivity active and ambient samples are cached
    key = (id(scene), float(cam.modulation_frequency), cam.n_phases, float(cam.integration_time))
    units = _PHOTONS_CACHE.get(key)
    if units is None:
        with torch.no_grad():
            act = Photons(responsivity=1.0).mean_samples(
                replace(cam, ambient_irradiance=0.0), scene
            )
            amb = Photons(responsivity=1.0).mean_samples(
                replace(cam, illumination_power=0.0, ambient_irradiance=1.0), scene
            )
        _PHOTONS_CACHE.clear()
        _RELAY_CACHE.clear()
        _PHOTONS_CACHE[key] = units = (act, amb)
    amb_irr = v.get("camera.ambient_irradiance", cam.ambient_irradiance)
    samples = (units[0] + units[1] * amb_irr) * v["photons.responsivity"]
    state = SimState(cam, scene, samples, None)
    sample_var = None  # per-sample noise variance (e-^2) when the clip has changed it
    chain = [(STAGE.get(_TERM_OF[e], 50), e) for e in model.effects]
    chain.append((STAGE["readout_fpn"], "_readout_fpn"))
    for _, e in sorted(chain):
        if e == "_readout_fpn":
            state.samples = _baseline_fpn(state.samples, v)
            continue
        t = build_term(e, v, model, for_chain=True)
        if e == "saturation":
            # the camera clips its noisy samples: the clip of the shot and read noise of each
            # sample, averaged (its mean bends over ~1 sd; the clipped part has no noise)
            var_e = state.samples.clamp_min(0) + v["camera.read_noise"] ** 2
            state.samples, sample_var = t.noisy_moments(state.samples, var_e)
        elif e == "multipath" and state.samples is samples:
            state = _multipath(t, state, units, key, amb_irr, v["photons.responsivity"])
        elif t is not None:
            state = t.apply(state)
    g = v["camera.conversion_gain"]
    dn = state.samples / g
    if sample_var is None:
        depth, a0, offset = depth_from_samples(dn, float(cam.modulation_frequency))
    else:  # fully clipped pixels have equal samples: decoded without a 0 / 0 in the gradient
        depth, a0, offset = _decode_flat_safe(dn, float(cam.modulation_frequency))
    f64 = torch.float64
    depth, a0, offset = depth[0, 0].to(f64), a0[0, 0].to(f64), offset[0, 0].to(f64)
    d_true = obs.scene_depth
    r_cam = K.SPEED_OF_LIGHT_AIR / (2.0 * float(cam.modulation_frequency))
    # the reading is the decoded depth in [0, R); where it is close to the scene depth it is
    # taken continuously across 0 / R (no wrapping in the baseline), where it is far (a mixture of
    # surfaces, a gross error) as decoded
    dev = depth - d_true
    dev = dev - r_cam * torch.round(dev / r_cam)
    mu_d = torch.where(dev.abs() < 0.25 * r_cam, d_true + dev, depth)
    wrap = None
    if "phase_wrapping" in model.effects:
        wrap = v["phase_wrapping.range"]
        mu_d = torch.remainder(mu_d, wrap)
    a0 = a0.clamp_min(1e-9)
    k_d = K.SPEED_OF_LIGHT_AIR / (4 * math.pi * float(cam.modulation_frequency))
    if sample_var is None:
        var = offset.clamp_min(0) / g + (v["camera.read_noise"] / g) ** 2 + 1.0 / 12.0
        s = torch.sqrt(2.0 * var / cam.n_phases)
        mu_a, sd_a = _rician(a0, s)
        var_d = (k_d * s / a0) ** 2
    else:
        s_perp, s_par = _clipped_noise(dn, sample_var / g**2 + 1.0 / 12.0)
        s = torch.sqrt(0.5 * (s_perp**2 + s_par**2))
        mu_a, sd_a = _rician(a0, s)
        sd_a = sd_a * s_par / s
        var_d = (k_d * s_perp / a0) ** 2
    var_d = var_d + obs.q_depth**2 / 12.0
    if "noise_floor" in model.effects:
        var_d = var_d + v["noise_floor.sigma"] ** 2
    if "saturation" in model.effects:
        # a pixel whose samples are all clipped has no phase: its depth is anywhere in [0, R),
        # so its spread is at most that of a uniform over the range
        var_d = torch.minimum(var_d, var_d.new_tensor(r_cam**2 / 12.0))
    if wrap is None:
        # a reading that the model itself moves to within a few sd of the wrap boundary (a clip
        # that pins the phase to a sample's direction reads exactly there) decodes as often near
        # 0 as near R: such a pixel is predicted on the side where its readings are. Not where
        # the scene itself is near the boundary: there a reading near 0 instead of near R is
        # what phase wrapping looks like
        lim = K.DIAG_WRAP_BOUNDARY_SD * var_d.sqrt()
        near = (dev_to_boundary(mu_d, r_cam) < lim) & (dev_to_boundary(d_true, r_cam) >= lim)
        near &= obs.known
        alt = mu_d + r_cam * torch.round((obs.m_d - mu_d) / r_cam)
        mu_d = torch.where(near, alt, mu_d)
    sd_a = torch.sqrt(sd_a**2 + obs.q_amp**2 / 12.0)
    tau = v["pixel_gain.rms"] * mu_a if "pixel_gain" in model.effects else 0.0
    return Prediction(mu_d, torch.sqrt(var_d), mu_a, sd_a, tau, a0, offset, s, wrap)


def _phasor(dn: torch.Tensor):
    """``Re X_1``, ``Im X_1`` (1, 1, H, W; float64), the DFT weights (exact zeros), and where
    the samples are flat (X_1 = 0)."""
    n = dn.shape[1]
    th = torch.arange(n, dtype=torch.float64) * (2 * math.pi / n)
    c, sn = torch.cos(th), torch.sin(th)
    c, sn = [torch.where(x.abs() < 1e-12, torch.zeros_like(x), x).view(1, n, 1, 1) for x in (c, sn)]
    d = dn.to(torch.float64)
    re, im = (d * c).sum(1, keepdim=True), -(d * sn).sum(1, keepdim=True)
    return re, im, c, sn, (re == 0) & (im == 0)


def _decode_flat_safe(dn: torch.Tensor, f: float):
    """Eq. (1) like :func:`~tof_fpn_torch.sim.depth_from_samples` (depth, amplitude, offset),
    with a finite gradient where the samples are all equal (amplitude 0, depth 0)."""
    re, im, _, _, flat = _phasor(dn)
    re_s = torch.where(flat, torch.ones_like(re), re)  # the 0 / 0 branch never differentiated
    phase = torch.remainder(torch.atan2(im, re_s), 2 * math.pi)
    amp = torch.where(flat, torch.zeros_like(re), torch.hypot(re_s, im) * (2.0 / dn.shape[1]))
    depth = phase * (K.SPEED_OF_LIGHT_AIR / (4 * math.pi * f))
    return depth, amp, dn.to(torch.float64).mean(1, keepdim=True)


def _clipped_noise(dn: torch.Tensor, var: torch.Tensor):
    """Noise of ``(2/N) X_1`` across and along the phasor (each (H, W), DN) for samples ``dn``
    (1, N, H, W) with unequal variances ``var`` (DN^2): the delta method through eq. (1). Equal
    variances ``v`` give ``sqrt(2 v / N)`` for both; a flat pixel (no phasor) gets the mean."""
    n = dn.shape[1]
    re, im, c, sn, flat = _phasor(dn)
    var = var.to(torch.float64)
    mag = torch.sqrt(torch.where(flat, torch.ones_like(re), re * re + im * im))
    # d phase / d R_n = -(Re sin + Im cos) / |X|^2, d |X| / d R_n = (Re cos - Im sin) / |X|
    perp = (var * ((re * sn + im * c) / mag) ** 2).sum(1)[0]
    par = (var * ((re * c - im * sn) / mag) ** 2).sum(1)[0]
    iso = 0.5 * var.sum(1)[0]
    perp, par = torch.where(flat[0, 0], iso, perp), torch.where(flat[0, 0], iso, par)
    return torch.sqrt(perp) * (2.0 / n), torch.sqrt(par) * (2.0 / n)


def dev_to_boundary(depth: torch.Tensor, r_cam: float) -> torch.Tensor:
    """Distance (m) of ``depth`` to the nearest multiple of the unambiguous range ``r_cam``."""
    return (depth - r_cam * torch.round(depth / r_cam)).abs()


def peak_samples(model: DiagnosisModel, p, depth: torch.Tensor, amp: torch.Tensor):
    """The largest of the N raw samples (DN) of pixels with ``depth`` (m) and amplitude ``amp``
    (DN) on the predicted offset: ``offset + A max_n cos(phi + 2 pi n / N)``."""
    n = model.camera.n_phases
    phi = depth * (4 * math.pi * float(model.camera.modulation_frequency) / K.SPEED_OF_LIGHT_AIR)
    th = torch.arange(n, dtype=torch.float64) * (2 * math.pi / n)
    cmax = torch.cos(phi.unsqueeze(-1) + th).amax(-1)
    return p.offset + amp * cmax


def copy_values(v: dict) -> dict:
    return copy.deepcopy(v)
