"""Raw-level ToF simulator, the paper's depth-domain noise model and test scenes (torch).

May import: torch, :mod:`tof_fpn_torch.runtime` (validity rule), :mod:`tof_fpn_torch.constants`.
Sits beside the run-time package, never below it: the simulator produces depth, amplitude and raw
samples that the stages, experiments and diagnosis consume.

* :mod:`~tof_fpn_torch.sim.camera` -- :class:`Camera` settings; eq. (1) decoder
  :func:`depth_from_samples` / :class:`DepthFromSamples`.
* :mod:`~tof_fpn_torch.sim.terms` -- the named physical terms (photons, shot noise, read noise);
  :mod:`~tof_fpn_torch.sim.readout` -- read-out FPN, ADC, impulsive pixels.
* :mod:`~tof_fpn_torch.sim.effects` -- effects beyond the default chain, one named term each
  (the diagnosis catalogue): :class:`FPNPattern`, :class:`CyclicError`, :class:`AmplitudeBias`,
  :class:`Vignetting`, :class:`TemporalDrift`, :class:`PhaseJitter`, :class:`PixelGain`,
  :class:`LensBlur`, :class:`Saturation`, :class:`Multipath` (the last five in
  :mod:`~tof_fpn_torch.sim.optics`, :mod:`~tof_fpn_torch.sim.multipath`);
  :func:`with_effect` inserts one in a chain.
* :mod:`~tof_fpn_torch.sim.simulator` -- :class:`Simulation` (camera + list of terms) and
  :func:`simulate`.
* :mod:`~tof_fpn_torch.sim.depth_model` -- eq. (2) noise and the eq. (10) FPN in the depth domain.
* :mod:`~tof_fpn_torch.sim.analysis` -- depth noise and FPN error against amplitude (Fig. 1).
* :mod:`~tof_fpn_torch.sim.scenes` -- :class:`Scene`, :func:`synthetic_scene` (Fig. 7) and
  :func:`planar_scene` (Sec. IV-A).

See docs/simulator.md for derivations and measured figures.
"""

from .analysis import AmplitudeCurve, depth_noise_vs_amplitude, fpn_error_vs_amplitude, loglog_slope
from .camera import (
    SPEED_OF_LIGHT_AIR,
    Camera,
    DepthFromSamples,
    depth_from_samples,
    unambiguous_range,
)
from .depth_model import (
    FPN_ALPHA,
    FPN_BETA,
    FPN_GAMMA,
    LOW_SENSING_THRESHOLD,
    DepthFPN,
    add_depth_fpn,
    add_depth_noise,
    depth_noise_std,
    fpn_intensity,
    fpn_pattern,
    noise_lambda,
    noise_lambda_for_psnr,
)
from .effects import (
    STAGE,
    AmplitudeBias,
    CyclicError,
    FPNPattern,
    PhaseJitter,
    TemporalDrift,
    with_effect,
)
from .multipath import Multipath
from .optics import (
    EdgeMixing,
    LensBlur,
    PixelGain,
    Saturation,
    Vignetting,
    edge_partners,
)
from .readout import ADC, ImpulsivePixels, PixelOffset, ReadoutFPN, default_terms
from .scenes import MATERIALS, Scene, planar_scene, synthetic_scene
from .simulator import SimResult, Simulation, simulate
from .terms import Joined, Photons, ReadNoise, ShotNoise, SimState, Term

__all__ = [
    "ADC",
    "STAGE",
    "AmplitudeBias",
    "CyclicError",
    "FPNPattern",
    "EdgeMixing",
    "LensBlur",
    "Multipath",
    "PhaseJitter",
    "PixelGain",
    "Saturation",
    "TemporalDrift",
    "Vignetting",
    "with_effect",
    "AmplitudeCurve",
    "FPN_ALPHA",
    "FPN_BETA",
    "FPN_GAMMA",
    "LOW_SENSING_THRESHOLD",
    "MATERIALS",
    "SPEED_OF_LIGHT_AIR",
    "Camera",
    "DepthFPN",
    "DepthFromSamples",
    "ImpulsivePixels",
    "Photons",
    "ReadNoise",
    "PixelOffset",
    "ReadoutFPN",
    "Scene",
    "ShotNoise",
    "SimResult",
    "SimState",
    "Simulation",
    "Joined",
    "Term",
    "add_depth_fpn",
    "add_depth_noise",
    "default_terms",
    "depth_from_samples",
    "depth_noise_vs_amplitude",
    "depth_noise_std",
    "edge_partners",
    "fpn_error_vs_amplitude",
    "fpn_intensity",
    "fpn_pattern",
    "loglog_slope",
    "noise_lambda",
    "noise_lambda_for_psnr",
    "planar_scene",
    "simulate",
    "synthetic_scene",
    "unambiguous_range",
]
