"""The model's prediction for every pixel: the deterministic terms run on the scene (no noise),
the samples are divided by the conversion gain ``g`` (DN) and decoded by eq. (1): ``A_0``, ``B``
and the depth, which is unwrapped around the scene depth unless a term folds it
(``phase_wrapping``). The noise law (:mod:`~tof_fpn_torch.diagnosis.noise`) gives the Rician
amplitude and the Gaussian depth spread, to which the terms add theirs (the jitter of
``noise_floor``) and the quantisation of the stored values adds ``q^2 / 12``.

:func:`predict` takes a :class:`~tof_fpn_torch.diagnosis.model.DiagnosisModel` and asks the terms
it holds through the hooks of :class:`~tof_fpn_torch.diagnosis.terms.base.Term`, never by name.
It sits below both the model and the terms (it imports neither), so that the terms can predict
with a changed model while they compute their starting values.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import torch

from .. import constants as K
from ..sim import STAGE, Camera, Photons, SimState, depth_from_samples
from .incidence import incidence_factor, incidence_sd, open_light
from .noise import decode_flat_safe, noise_law
from .readout import apply_readout
from .terms.base import Chain

__all__ = ["WRAP_BOUNDARY_SD", "Prediction", "dev_to_boundary", "predict"]

#: A pixel that the model moves to within this many depth sd of the wrap boundary (0 / R), its
#: scene depth not that close, is predicted on the side where its readings are (same phase).
WRAP_BOUNDARY_SD: float = 4.0
#: the baseline's read-out FPN in the mean chain (not a catalogue term)
_BASELINE_FPN = "_readout_fpn"


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


#: the baseline FPN's column waves of the last ``(width, dtype)``: computed once, not per call
_WAVES: dict = {}


def _waves(w: int, dt: torch.dtype) -> tuple:
    key = (w, dt)
    out = _WAVES.get(key)
    if out is None:
        x = torch.arange(w, dtype=torch.float64)
        w23 = K.FPN_FREQUENCIES[0]
        out = (torch.cos(w23 * x).to(dt), torch.sin(w23 * x).to(dt), torch.cos(math.pi * x).to(dt))
        _WAVES.clear()
        _WAVES[key] = out
    return out


def _baseline_fpn(samples: torch.Tensor, v: dict) -> torch.Tensor:
    n, w = samples.shape[1], samples.shape[3]
    c23, s23, c_pi = _waves(w, samples.dtype)
    p = (
        v["readout_fpn.cos_2pi3"] * c23
        - v["readout_fpn.sin_2pi3"] * s23
        + v["readout_fpn.cos_pi"] * c_pi
    )
    th = torch.arange(n, dtype=torch.float64) * (2 * math.pi / n)
    wn = torch.cos(th - v["readout_fpn.sample_phase"])
    return samples + (wn.view(1, n, 1, 1) * p.view(1, 1, 1, w)).to(samples.dtype)


#: the last scene's unit images: ``(scene, camera key, units)``. The entry holds the scene
#: itself, so no other scene can take its address while the entry lives; a scene of equal
#: content (``obs.scene()`` builds a new one on every call) is served too.
_PHOTONS: list = [None]


def _same_scene(a, b) -> bool:
    """``a`` is ``b`` or has the same depth and reflectance (dtype, device, shape, values)."""
    if a is b:
        return True
    for x, y in ((a.depth, b.depth), (a.reflectance, b.reflectance)):
        if x.dtype != y.dtype or x.device != y.device or x.shape != y.shape:
            return False
        if not torch.equal(x, y):
            return False
    return True


def _photon_units(cam: Camera, scene) -> tuple[tuple, tuple]:
    """The unit-responsivity active and ambient samples of ``scene`` and their cache key (the
    camera settings they depend on): the photo-charge is linear in the responsivity and in the
    ambient irradiance, so they are computed once per scene and camera."""
    key = (
        float(cam.modulation_frequency),
        cam.n_phases,
        float(cam.integration_time),
        float(cam.illumination_power),
    )
    entry = _PHOTONS[0]  # one read: another thread may replace the entry meanwhile
    if entry is not None and entry[1] == key and _same_scene(entry[0], scene):
        return entry[2], key
    with torch.no_grad():
        act = Photons(responsivity=1.0).mean_samples(replace(cam, ambient_irradiance=0.0), scene)
        amb = Photons(responsivity=1.0).mean_samples(
            replace(cam, illumination_power=0.0, ambient_irradiance=1.0), scene
        )
    units = (act, amb)
    _PHOTONS[0] = (scene, key, units)
    return units, key


def _mean_chain(model, v: dict, state: SimState, chain: Chain) -> SimState:
    """The noise-free samples after every term of the model and the baseline's read-out FPN, in
    the simulator's stage order (``Term.apply_mean``; terms that do not enter the chain pass)."""
    steps = [(STAGE.get(t.sim_name or t.name, 50), t.name, t) for t in model.terms]
    steps.append((STAGE["readout_fpn"], _BASELINE_FPN, None))
    for _, _, term in sorted(steps, key=lambda s: s[:2]):
        if term is None:
            state.samples = _baseline_fpn(state.samples, v)
            state.samples = apply_readout(state.samples, model, v["camera.conversion_gain"])
        else:
            state = term.apply_mean(state, v, model, chain)
    return state


def predict(model, obs, v: dict | None = None, scene=None) -> Prediction:
    """Model predictions for ``obs`` with values ``v`` (default ``model.values``; tensors keep
    the graph). ``scene``: a cached :class:`~tof_fpn_torch.sim.Scene` (default ``obs.scene()``)."""
    v = model.values if v is None else v
    scene = obs.scene() if scene is None else scene
    cam = model.camera
    units, key = _photon_units(cam, scene)
    amb_irr = v.get("camera.ambient_irradiance", cam.ambient_irradiance)
    inc = incidence_factor(scene, v)  # the angle of incidence (None: not in the model)
    active = units[0] if inc is None else units[0] * inc
    samples = (active + units[1] * amb_irr) * v["photons.responsivity"]
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
    light = open_light(scene, v, obs, mu_a)  # where the angle leaves a pixel's light open
    if light is not None:
        var_d = var_d / light**2
    var_d = _terms_depth_variance(model, v, var_d + obs.q_depth**2 / 12.0, r_cam)
    if wrap is None:
        mu_d = _boundary_side(mu_d, var_d, obs, r_cam)
    sd_a = torch.sqrt(sd_a**2 + obs.q_amp**2 / 12.0)
    tau = _amplitude_tau(model, v, mu_a)
    open_angle = incidence_sd(scene, v, mu_a)  # the baseline's: where a surface's angle is open
    if open_angle is not None:  # (no square root of a sum that is 0 in most pixels)
        tau = open_angle if isinstance(tau, float) else torch.sqrt(tau * tau + open_angle**2)
    k = 4.0 * math.pi * f / K.SPEED_OF_LIGHT_AIR
    tau_d = _random_sd([t.depth_mean_sd(v, a0, k) for t in model.terms])
    return Prediction(mu_d, torch.sqrt(var_d), mu_a, sd_a, tau, a0, offset, s, wrap, tau_d)


def _reading(depth: torch.Tensor, d_true: torch.Tensor, r_cam: float) -> torch.Tensor:
    """The reading is the decoded depth in [0, R); where it is close to the scene depth it is
    taken continuously across 0 / R (no wrapping in the baseline), where it is far (a mixture of
    surfaces, a gross error) as decoded."""
    dev = depth - d_true
    dev = dev - r_cam * torch.round(dev / r_cam)
    return torch.where(dev.abs() < 0.25 * r_cam, d_true + dev, depth)


def _terms_depth_variance(model, v: dict, var_d, r_cam: float):
    """The depth variance with what the terms add (``Term.depth_variance``), then capped by
    their limits (``Term.depth_variance_limit``)."""
    for t in model.terms:
        add = t.depth_variance(v)
        if add is not None:
            var_d = var_d + add
    for t in model.terms:
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
    scene_dev, inside = _scene_boundary(obs, r_cam)
    near = (dev_to_boundary(mu_d, r_cam) < lim) & (scene_dev >= lim)
    if inside is not None:
        near |= inside
    near &= obs.known
    alt = mu_d + r_cam * torch.round((obs.m_d - mu_d) / r_cam)
    return torch.where(near, alt, mu_d)


#: the last observations' scene distances to the wrap boundary: ``(scene depth, known, R,
#: frequency stated, value)``; the entry holds the tensors, so no other can take their address
_SCENE_BOUNDARY: list = [None]


def _scene_boundary(obs, r_cam: float):
    """``(distance of the scene depth to the wrap boundary, where the scene lies inside the
    camera's stated range or None)``, computed once per observations (every prediction needs
    them)."""
    entry = _SCENE_BOUNDARY[0]  # one read: another thread may replace the entry meanwhile
    stated = obs.frequency is not None
    if entry is None or entry[0] is not obs.scene_depth or entry[1] != r_cam or entry[2] != stated:
        # the camera decodes into [0, R): where the scene lies inside its stated range, a
        # reading across 0 / R is the decoder's fold of noise or of a bias, not a scene beyond
        inside = obs.scene_depth < r_cam if stated else None
        entry = (obs.scene_depth, r_cam, stated, (dev_to_boundary(obs.scene_depth, r_cam), inside))
        _SCENE_BOUNDARY[0] = entry
    return entry[3]


def _amplitude_tau(model, v: dict, mu_a):
    """Sd of the random effects on the amplitude means (``Term.amplitude_sd``; 0.0: none)."""
    return _random_sd([t.amplitude_sd(v, mu_a) for t in model.terms])


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
