"""Monte-Carlo characterisation of a simulation: depth noise and FPN error against amplitude.

The simulator's counterpart of the paper's Fig. 1 (depth variance against amplitude, fitted by
eq. 2) and of Sec. II-B (FPN matters more as the amplitude falls).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import torch

from .readout import ADC
from .scenes import Scene
from .simulator import Simulation
from .terms import Photons

__all__ = ["AmplitudeCurve", "depth_noise_vs_amplitude", "fpn_error_vs_amplitude", "loglog_slope"]


@dataclass
class AmplitudeCurve:
    """One value per amplitude level (1-D tensors of equal length).

    Attributes:
        amplitude: mean measured amplitude of the level (DN).
        value: temporal depth std (``depth_noise_vs_amplitude``) or mean absolute FPN depth
            error (``fpn_error_vs_amplitude``), metres.
        offset: mean measured offset of the level (DN).
    """

    amplitude: torch.Tensor
    value: torch.Tensor
    offset: torch.Tensor

    @property
    def slope(self) -> float:
        """Least-squares slope of ``log(value)`` against ``log(amplitude)``."""
        return loglog_slope(self.amplitude, self.value)


def loglog_slope(x: torch.Tensor, y: torch.Tensor) -> float:
    """Least-squares slope of ``log y`` against ``log x`` (both positive 1-D tensors)."""
    if x.dim() != 1 or x.shape != y.shape or x.numel() < 2:
        raise ValueError(
            f"x and y must be 1-D of equal length >= 2, got {list(x.shape)} and {list(y.shape)}"
        )
    if bool((x <= 0).any()) or bool((y <= 0).any()):
        raise ValueError("x and y must be > 0 for a log-log fit")
    lx, ly = torch.log(x.double()), torch.log(y.double())
    lx = lx - lx.mean()
    return float((lx * (ly - ly.mean())).sum() / (lx * lx).sum())


def depth_noise_vs_amplitude(
    sim: Simulation,
    *,
    depth_range: tuple[float, float] = (1.0, 3.0),
    reflectance: float = 0.5,
    height: int = 16,
    width: int = 24,
    frames: int = 64,
    seed: int = 0,
) -> AmplitudeCurve:
    """Temporal depth noise against amplitude (Fig. 1 of the paper, by Monte Carlo).

    The scene is a reflectance-``reflectance`` target whose depth rises linearly across the
    columns over ``depth_range`` (amplitude ~ 1 / depth^2 while the ambient offset stays); each
    column is one amplitude level, its noise the per-pixel temporal std over ``frames`` averaged
    over the column.
    """
    d0, d1 = depth_range
    d = torch.linspace(d0, d1, width, dtype=torch.float64).view(1, 1, 1, width)
    d = d.expand(1, 1, height, width).contiguous().float()
    out = sim.run(Scene(d, torch.full_like(d, reflectance)), frames, seed=seed)
    sigma = out.depth.view(frames, height, width).std(dim=0).mean(dim=0)
    amp = out.amplitude.view(frames, height, width).mean(dim=(0, 1))
    off = out.offset.view(frames, height, width).mean(dim=(0, 1))
    return AmplitudeCurve(amp, sigma, off)


def fpn_error_vs_amplitude(
    sim: Simulation,
    *,
    depth: float = 2.5,
    reflectance_range: tuple[float, float] = (0.01, 1.0),
    height: int = 24,
    width: int = 60,
) -> AmplitudeCurve:
    """Mean absolute depth error caused by the FPN terms, against amplitude, without noise.

    Runs ``sim`` reduced to its deterministic terms (photons, read-out FPN, ADC without rounding)
    with and without the ``readout_fpn`` term on a flat target whose reflectance rises
    log-uniformly down the rows (one amplitude level per row; the column FPN varies along them).
    """
    r0, r1 = reflectance_range
    rho = torch.logspace(
        torch.log10(torch.tensor(r0)).item(), torch.log10(torch.tensor(r1)).item(), height
    )
    rho = rho.view(1, 1, height, 1).expand(1, 1, height, width).contiguous()
    scene = Scene(torch.full_like(rho, depth), rho)
    photons = sim.term("photons")
    fpn = sim.term("readout_fpn")
    if not isinstance(photons, Photons):
        raise ValueError("sim's 'photons' term must be a Photons")
    cam = dataclasses.replace(sim.camera)
    clean = Simulation(cam, [photons, ADC(quantize=False)]).run(scene)
    with_fpn = Simulation(cam, [photons, fpn, ADC(quantize=False)]).run(scene)
    err = (with_fpn.depth - clean.depth).abs().mean(dim=3).flatten()
    return AmplitudeCurve(
        clean.amplitude.mean(dim=3).flatten(), err, clean.offset.mean(dim=3).flatten()
    )
