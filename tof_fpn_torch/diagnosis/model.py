"""The diagnosing model: a simulator chain whose noise-free output is the mean, plus the noise law.

Baseline (issue 10): ideal sinusoidal correlation (:class:`~tof_fpn_torch.sim.Photons`, amplitude
``k rho / d^2`` up to the camera constants, ``k`` = ``photons.responsivity`` fitted), offset ``B``
(active light over the demodulation contrast plus ambient), photon shot and read noise (the
conversion gain ``g`` and the read noise fitted), column read-out FPN at ``2 pi / 3`` and ``pi``
(:class:`~tof_fpn_torch.sim.ReadoutFPN`'s offsets ``o_n(x) = p(x) cos(2 pi n / N - psi)``; the
three signed amplitudes of ``p`` and ``psi`` fitted). No saturation, no wrapping.

Prediction for every pixel: the deterministic terms run on the scene (no noise), the samples are
divided by ``g`` (DN) and decoded by eq. (1): ``A_0``, ``B`` and the depth, which is unwrapped
around the scene depth unless a term folds it (``phase_wrapping``). The noise law
(:mod:`~tof_fpn_torch.diagnosis.noise`) gives the Rician amplitude and the Gaussian depth spread,
to which the terms add theirs (the jitter of ``noise_floor``) and the quantisation of the stored
values adds ``q^2 / 12``. The catalogue terms enter through the hooks of
:class:`~tof_fpn_torch.diagnosis.terms.base.Term`, never by name.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import torch

from .. import constants as K
from ..sim import (
    ADC,
    STAGE,
    Camera,
    Joined,
    Photons,
    ReadNoise,
    ReadoutFPN,
    ShotNoise,
    SimState,
    Simulation,
    depth_from_samples,
)
from .catalogue import CATALOGUE
from .noise import decode_flat_safe, noise_law
from .params import ParamSpec
from .readout import READOUT_KEYS, apply_readout, readout_maps
from .terms.base import Chain, Term

__all__ = ["CORE_SPECS", "WRAP_BOUNDARY_SD", "DiagnosisModel", "Prediction", "predict"]

#: always fitted
CORE_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("photons.responsivity", "log", 1.0, charge=True),
    ParamSpec("camera.conversion_gain", "log", 1.0, "e-/DN"),
    ParamSpec("camera.read_noise", "rootabs", 1.0, "e-", charge=True),
    ParamSpec("camera.ambient_irradiance", "abs", 0.1, "W/m^2"),
    ParamSpec("readout_fpn.cos_2pi3", "lin", 1.0, "e-", charge=True),
    ParamSpec("readout_fpn.sin_2pi3", "lin", 1.0, "e-", charge=True),
    ParamSpec("readout_fpn.cos_pi", "lin", 1.0, "e-", charge=True),
    ParamSpec("readout_fpn.sample_phase", "lin", 1.0, "rad"),
)
#: A pixel that the model moves to within this many depth sd of the wrap boundary (0 / R), its
#: scene depth not that close, is predicted on the side where its readings are (same phase).
WRAP_BOUNDARY_SD: float = 4.0
#: the baseline's read-out FPN in the mean chain (not a catalogue term)
_BASELINE_FPN = "_readout_fpn"


@dataclass
class DiagnosisModel:
    """Camera, fitted values (``"owner.field"`` -> float), the catalogue effects in the model
    (in the order they were added), the closed-form profiles (``"columns"``, ``"rows"``, the
    baseline's read-out columns), the keys of values the recording states (``fixed``: not
    fitted) and whether the baseline holds random column read-out offsets and gains
    (``random_columns``, :mod:`~tof_fpn_torch.diagnosis.readout`)."""

    camera: Camera
    values: dict
    effects: list = field(default_factory=list)
    profiles: dict = field(default_factory=dict)
    frame_interval: float = 1.0
    impulsive_level: float = 1e-6
    fpn_scale: float = 1.0
    fixed: frozenset = frozenset()
    random_columns: bool = False

    def copy(self) -> DiagnosisModel:
        return DiagnosisModel(
            replace(self.camera),
            dict(self.values),
            list(self.effects),
            {k: v.clone() for k, v in self.profiles.items()},
            self.frame_interval,
            self.impulsive_level,
            self.fpn_scale,
            self.fixed,
            self.random_columns,
        )

    def terms(self) -> list[Term]:
        """The catalogue terms in the model, in the order they were added."""
        return [CATALOGUE[e] for e in self.effects]

    def wrap_range(self, v: dict | None = None):
        """The range (m) a term of the model folds the depth into (None: no folding)."""
        v = self.values if v is None else v
        for t in self.terms():
            r = t.wrap_range(v)
            if r is not None:
                return r
        return None

    def specs(self) -> list[ParamSpec]:
        """Every fitted scalar of the model (core + its effects)."""
        out = []
        for s in CORE_SPECS:
            if s.key in self.fixed:
                continue
            if s.key.startswith(("readout_fpn.cos", "readout_fpn.sin")):
                s = replace(s, scale=self.fpn_scale)
            elif s.key == "camera.read_noise":
                s = replace(s, scale=self.fpn_scale**2)
            out.append(s)
        for t in self.terms():
            out.extend(s for s in t.specs if s.key not in self.fixed)
        return out

    def n_parameters(self) -> float:
        """Number of fitted parameters (closed-form estimates count their effective degrees of
        freedom, ``Term.effective_parameters``)."""
        extra = sum((t.effective_parameters(self.values) for t in self.terms()), 0.0)
        # the read-out columns count once: as a term's profiles, or as the baseline's own
        owned = any(set(READOUT_KEYS) & set(t.profile_keys) for t in self.terms())
        if READOUT_KEYS[0] in self.profiles and not owned:
            extra += float(self.values.get("readout_fpn.columns_dof", 0.0))
        return len(self.specs()) + extra

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
        for k in CATALOGUE[name].profile_keys:
            m.profiles.pop(k, None)
        return m

    def readout_fpn(self) -> ReadoutFPN:
        """The baseline FPN as the simulator's :class:`ReadoutFPN` (amplitude >= 0, phases)."""
        v = self.values
        a2 = math.hypot(v["readout_fpn.cos_2pi3"], v["readout_fpn.sin_2pi3"])
        th2 = math.atan2(v["readout_fpn.sin_2pi3"], v["readout_fpn.cos_2pi3"])
        cpi = v["readout_fpn.cos_pi"]
        off, gain = readout_maps(self, self.camera.n_phases, float(v["camera.conversion_gain"]))
        return ReadoutFPN(
            frequencies=K.FPN_FREQUENCIES,
            offset_amplitudes=(a2, abs(cpi)),
            gain_amplitudes=(0.0, 0.0),
            spatial_phases=(th2, 0.0 if cpi >= 0 else math.pi),
            sample_phase=v["readout_fpn.sample_phase"],
            random_offset=0.0,
            random_gain=0.0,
            offset_map=off,
            gain_map=gain,
        )

    def simulation_camera(self) -> Camera:
        f = float(self.camera.modulation_frequency)
        wrap = self.wrap_range()
        if wrap is not None:
            f = K.SPEED_OF_LIGHT_AIR / (2.0 * wrap)
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
        for term in self.terms():
            t = term.simulator_term(v, self)
            if t is None:
                continue
            same = next((i for i, x in enumerate(terms) if x.name == t.name), None)
            if same is None:
                terms.append(t)
            else:  # two forms of one effect: one stage, applied in turn
                prev = terms[same]
                parts = prev.parts if isinstance(prev, Joined) else (prev,)
                terms[same] = Joined(parts + (t,), t.name)
        terms.sort(key=lambda t: STAGE.get(t.name, 50))
        return Simulation(self.simulation_camera(), terms)


@dataclass
class Prediction:
    """Per-pixel (H, W) model predictions (float64): depth mean / sd per frame, amplitude mean /
    sd per frame (Rician), ``tau_a`` (sd of the pixel-gain random effect on the amplitude mean),
    ``tau_d`` (sd of a random effect fixed over time on the depth mean, m; 0.0: none),
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
    tau_d: torch.Tensor | float = 0.0


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


def _photon_units(cam: Camera, scene) -> tuple[tuple, tuple]:
    """The unit-responsivity active and ambient samples of ``scene`` and their cache key: the
    photo-charge is linear in the responsivity and in the ambient irradiance, so they are
    computed once per scene and camera."""
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
        _PHOTONS_CACHE[key] = units = (act, amb)
    return units, key


def _mean_chain(model: DiagnosisModel, v: dict, state: SimState, chain: Chain) -> SimState:
    """The noise-free samples after every term of the model and the baseline's read-out FPN, in
    the simulator's stage order (``Term.apply_mean``; terms that do not enter the chain pass)."""
    steps = [(STAGE.get(t.sim_name or t.name, 50), t.name) for t in model.terms()]
    steps.append((STAGE["readout_fpn"], _BASELINE_FPN))
    for _, name in sorted(steps):
        if name == _BASELINE_FPN:
            state.samples = _baseline_fpn(state.samples, v)
            state.samples = apply_readout(state.samples, model, v["camera.conversion_gain"])
        else:
            state = CATALOGUE[name].apply_mean(state, v, model, chain)
    return state


def predict(model: DiagnosisModel, obs, v: dict | None = None, scene=None) -> Prediction:
    """Model predictions for ``obs`` with values ``v`` (default ``model.values``; tensors keep
    the graph). ``scene``: a cached :class:`~tof_fpn_torch.sim.Scene` (default ``obs.scene()``)."""
    v = model.values if v is None else v
    scene = obs.scene() if scene is None else scene
    cam = model.camera
    units, key = _photon_units(cam, scene)
    amb_irr = v.get("camera.ambient_irradiance", cam.ambient_irradiance)
    samples = (units[0] + units[1] * amb_irr) * v["photons.responsivity"]
    chain = Chain(samples, units, key, amb_irr, v["photons.responsivity"])
    state = _mean_chain(model, v, SimState(cam, scene, samples, None), chain)
    g = v["camera.conversion_gain"]
    dn = state.samples / g
    f = float(cam.modulation_frequency)
    if chain.sample_var is None:
        depth, a0, offset = depth_from_samples(dn, f)
    else:  # fully clipped pixels have equal samples: decoded without a 0 / 0 in the gradient
        depth, a0, offset = decode_flat_safe(dn, f)
    f64 = torch.float64
    depth, a0, offset = depth[0, 0].to(f64), a0[0, 0].to(f64), offset[0, 0].to(f64)
    r_cam = K.SPEED_OF_LIGHT_AIR / (2.0 * f)
    mu_d = _reading(depth, obs.scene_depth, r_cam)
    wrap = model.wrap_range(v)
    if wrap is not None:
        mu_d = torch.remainder(mu_d, wrap)
    a0 = a0.clamp_min(1e-9)
    mu_a, sd_a, var_d, s = noise_law(cam, v, dn, a0, offset, chain.sample_var)
    var_d = _terms_depth_variance(model, v, var_d + obs.q_depth**2 / 12.0, r_cam)
    if wrap is None:
        mu_d = _boundary_side(mu_d, var_d, obs, r_cam)
    sd_a = torch.sqrt(sd_a**2 + obs.q_amp**2 / 12.0)
    tau = _amplitude_tau(model, v, mu_a)
    k = 4.0 * math.pi * f / K.SPEED_OF_LIGHT_AIR
    tau_d = _random_sd([t.depth_mean_sd(v, a0, k) for t in model.terms()])
    return Prediction(mu_d, torch.sqrt(var_d), mu_a, sd_a, tau, a0, offset, s, wrap, tau_d)


def _reading(depth: torch.Tensor, d_true: torch.Tensor, r_cam: float) -> torch.Tensor:
    """The reading is the decoded depth in [0, R); where it is close to the scene depth it is
    taken continuously across 0 / R (no wrapping in the baseline), where it is far (a mixture of
    surfaces, a gross error) as decoded."""
    dev = depth - d_true
    dev = dev - r_cam * torch.round(dev / r_cam)
    return torch.where(dev.abs() < 0.25 * r_cam, d_true + dev, depth)


def _terms_depth_variance(model: DiagnosisModel, v: dict, var_d, r_cam: float):
    """The depth variance with what the terms add (``Term.depth_variance``), then capped by
    their limits (``Term.depth_variance_limit``)."""
    terms = model.terms()
    for t in terms:
        add = t.depth_variance(v)
        if add is not None:
            var_d = var_d + add
    for t in terms:
        lim = t.depth_variance_limit(r_cam)
        if lim is not None:
            var_d = torch.minimum(var_d, var_d.new_tensor(lim))
    return var_d


def _boundary_side(mu_d, var_d, obs, r_cam: float):
    """A reading that the model itself moves to within a few sd of the wrap boundary (a clip
    that pins the phase to a sample's direction reads exactly there) decodes as often near 0 as
    near R: such a pixel is predicted on the side where its readings are. Not where the scene
    itself is near the boundary: there a reading near 0 instead of near R is what phase wrapping
    looks like."""
    lim = WRAP_BOUNDARY_SD * var_d.sqrt()
    near = (dev_to_boundary(mu_d, r_cam) < lim) & (dev_to_boundary(obs.scene_depth, r_cam) >= lim)
    if obs.frequency is not None:
        # the camera decodes into [0, R): where the scene lies inside its stated range, a
        # reading across 0 / R is the decoder's fold of noise or of a bias, not a scene beyond
        near |= obs.scene_depth < r_cam
    near &= obs.known
    alt = mu_d + r_cam * torch.round((obs.m_d - mu_d) / r_cam)
    return torch.where(near, alt, mu_d)


def _amplitude_tau(model: DiagnosisModel, v: dict, mu_a):
    """Sd of the random effects on the amplitude means (``Term.amplitude_sd``; 0.0: none)."""
    return _random_sd([t.amplitude_sd(v, mu_a) for t in model.terms()])


def _random_sd(sds: list):
    """The sd of the sum of independent random effects of sds ``sds`` (None: a term without
    one; 0.0 when there is none)."""
    sds = [x for x in sds if x is not None]
    if not sds:
        return 0.0
    return sds[0] if len(sds) == 1 else torch.sqrt(sum(x * x for x in sds))


def dev_to_boundary(depth: torch.Tensor, r_cam: float) -> torch.Tensor:
    """Distance (m) of ``depth`` to the nearest multiple of the unambiguous range ``r_cam``."""
    return (depth - r_cam * torch.round(depth / r_cam)).abs()
