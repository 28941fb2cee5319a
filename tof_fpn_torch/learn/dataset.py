r"""Training data for learned depth networks from the raw-level simulator (domain randomisation).

:class:`SimulatedFrames` is an endless (or ``length``-long) :class:`torch.utils.data.IterableDataset`
of low-sensing ToF frames. Sample ``i`` is a pure function of ``(seed, i)``: a scene and camera
settings drawn from :class:`Ranges`, simulated through the raw chain (photons, shot noise, read-out
FPN, read noise, ADC; :mod:`tof_fpn_torch.sim`) and decoded by eq. (1). With several
``DataLoader`` workers, worker ``w`` of ``n`` yields the samples ``i = w, w + n, w + 2 n, ...``, so
no two workers yield the same sample and the union is the same set whatever ``n`` is.

Each item is ``(depth, amplitude, target, valid)``, each (1, H, W) float32 (``valid`` bool):
measured depth in metres (invalid pixels as the decoder gives them), amplitude in DN, the scene's
ground-truth depth, and :func:`~tof_fpn_torch.runtime.valid_mask` of depth and amplitude.

Randomised, with the ranges in :class:`Ranges` (documented defaults):

* scene: :func:`~tof_fpn_torch.sim.synthetic_scene` (Fig. 7-like) or
  :func:`~tof_fpn_torch.sim.planar_scene` (Sec. IV-A boards), a fresh seed each;
* amplitude scale: the illumination power (log-uniform), which sets where the frame sits relative
  to the low-sensing regime;
* integration time: log-uniform over the paper's low-sensing captures (50-400 us);
* FPN pattern: the periodic read-out offsets at 2pi/3 and pi (each amplitude uniform, random spatial
  phases), broadband random column offsets, and the split over the N samples (``psi``);
* noise: read noise uniform; shot noise always.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch.utils.data import IterableDataset, get_worker_info

from ..runtime.validity import valid_mask
from ..sim import Camera, Simulation, planar_scene, synthetic_scene
from ..sim.readout import ReadoutFPN, default_terms

__all__ = ["Ranges", "SimulatedFrames", "draw_sample"]


@dataclass(frozen=True)
class Ranges:
    """The domain-randomisation ranges of :class:`SimulatedFrames` (physical units).

    Attributes:
        illumination_power_w: (low, high) illumination power, W, log-uniform.
        integration_time_s: (low, high) integration time per sample, s, log-uniform.
        periodic_offset_e: (low, high) amplitude of each periodic read-out offset (2pi/3, pi), e-.
        random_offset_e: (low, high) broadband per-column read-out offset rms, e-.
        read_noise_e: (low, high) read noise, e- rms.
        planar_share: probability of a planar (boards) scene instead of the Fig. 7-like one.
    """

    illumination_power_w: tuple[float, float] = (0.5, 8.0)
    integration_time_s: tuple[float, float] = (50e-6, 400e-6)
    periodic_offset_e: tuple[float, float] = (0.0, 120.0)
    random_offset_e: tuple[float, float] = (0.0, 40.0)
    read_noise_e: tuple[float, float] = (5.0, 20.0)
    planar_share: float = 0.5

    def validate(self) -> Ranges:
        for name in (
            "illumination_power_w",
            "integration_time_s",
            "periodic_offset_e",
            "random_offset_e",
            "read_noise_e",
        ):
            lo, hi = getattr(self, name)
            if not (math.isfinite(lo) and math.isfinite(hi) and 0 <= lo <= hi):
                raise ValueError(
                    f"{name} must be (low, high) with 0 <= low <= high, got {(lo, hi)}"
                )
        for name in ("illumination_power_w", "integration_time_s"):
            if getattr(self, name)[0] <= 0:
                raise ValueError(f"{name} must be > 0 (log-uniform), got {getattr(self, name)}")
        if not 0.0 <= self.planar_share <= 1.0:
            raise ValueError(f"planar_share must lie in [0, 1], got {self.planar_share!r}")
        return self


def _uniform(g: torch.Generator, lo: float, hi: float) -> float:
    return lo + (hi - lo) * float(torch.rand((), generator=g, dtype=torch.float64))


def _log_uniform(g: torch.Generator, lo: float, hi: float) -> float:
    return math.exp(_uniform(g, math.log(lo), math.log(hi)))


def draw_sample(
    seed: int, index: int, size: tuple[int, int], ranges: Ranges = Ranges()
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, dict]:
    """Sample ``index`` of the stream ``seed``: ``(depth, amplitude, target, valid, settings)``,
    each (1, H, W) (the first three float32 in metres / DN / metres, ``valid`` bool)."""
    g = torch.Generator().manual_seed(int(seed) * 1_000_003 + int(index))
    h, w = size
    planar = _uniform(g, 0.0, 1.0) < ranges.planar_share
    scene_seed = int(torch.randint(0, 2**31 - 1, (), generator=g))
    scene = (planar_scene if planar else synthetic_scene)(h, w, seed=scene_seed)
    camera = Camera(
        integration_time=_log_uniform(g, *ranges.integration_time_s),
        illumination_power=_log_uniform(g, *ranges.illumination_power_w),
        read_noise=_uniform(g, *ranges.read_noise_e),
    )
    terms = default_terms()
    fpn = ReadoutFPN(
        offset_amplitudes=(
            _uniform(g, *ranges.periodic_offset_e),
            _uniform(g, *ranges.periodic_offset_e),
        ),
        spatial_phases=(_uniform(g, 0.0, 2 * math.pi), _uniform(g, 0.0, 2 * math.pi)),
        sample_phase=_uniform(g, 0.0, 2 * math.pi),
        random_offset=_uniform(g, *ranges.random_offset_e),
        seed=int(torch.randint(0, 2**31 - 1, (), generator=g)),
    )
    terms = [fpn if t.name == "readout_fpn" else t for t in terms]
    out = Simulation(camera, terms).run(
        scene, 1, seed=int(torch.randint(0, 2**31 - 1, (), generator=g))
    )
    depth, amp = out.depth[0].float(), out.amplitude[0].float()
    target = scene.depth[0].float()
    valid = valid_mask(depth, amp)
    settings = {
        "scene": "planar" if planar else "synthetic",
        "scene_seed": scene_seed,
        "integration_time_s": camera.integration_time,
        "illumination_power_w": camera.illumination_power,
        "read_noise_e": camera.read_noise,
        "periodic_offset_e": list(fpn.offset_amplitudes),
        "random_offset_e": fpn.random_offset,
    }
    return depth, amp, target, valid, settings


class SimulatedFrames(IterableDataset):
    """Simulated low-sensing frames with domain randomisation (see the module docstring).

    Args:
        size: (H, W) of every frame (>= 16 each).
        seed: the stream; sample ``i`` depends only on ``(seed, i)``.
        length: number of samples, or None for an endless stream.
        ranges: the randomisation ranges.

    Example:
        >>> ds = SimulatedFrames((32, 40), seed=0, length=2)
        >>> [tuple(t.shape) for t in next(iter(ds))[:4]]
        [(1, 32, 40), (1, 32, 40), (1, 32, 40), (1, 32, 40)]
    """

    def __init__(
        self,
        size: tuple[int, int] = (96, 96),
        seed: int = 0,
        length: int | None = None,
        ranges: Ranges = Ranges(),
    ) -> None:
        super().__init__()
        h, w = size
        if any(isinstance(v, bool) or not isinstance(v, int) or v < 16 for v in (h, w)):
            raise ValueError(f"size must be (H, W) ints >= 16, got {size!r}")
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise ValueError(f"seed must be an int >= 0, got {seed!r}")
        if length is not None and (
            isinstance(length, bool) or not isinstance(length, int) or length < 0
        ):
            raise ValueError(f"length must be None or an int >= 0, got {length!r}")
        self.size = (h, w)
        self.seed = seed
        self.length = length
        self.ranges = ranges.validate()

    def __iter__(self):
        info = get_worker_info()
        worker, workers = (0, 1) if info is None else (info.id, info.num_workers)
        i = worker
        while self.length is None or i < self.length:
            depth, amp, target, valid, _ = draw_sample(self.seed, i, self.size, self.ranges)
            yield depth, amp, target, valid
            i += workers
