"""The temporal filter as a stage of the contract: the frames of one recording, the batch being
the time axis (:class:`TemporalSequence`).

:class:`~tof_fpn_torch.runtime.TemporalFilter` is the streaming form (one frame in, its state
passed in and out: live use and export); :class:`TemporalSequence` runs it over ``(T, C, H, W)``
frames in time order from a fresh state and records, per frame, how many pixels the motion guard
restarted. It is causal: the first ``k`` frames come out the same whether or not later ones
follow.
"""

# no `from __future__ import annotations`: TorchScript reads the annotations below

import torch

from .. import constants as K
from .stage import RecordField, Setting, Stage, check_settings
from .temporal import TemporalFilter

__all__ = ["TemporalSequence"]


class TemporalSequence(Stage):
    """The temporal filter over the frames of one recording in time order.

    Args:
        alpha, guard, sigma, noise_k, persistence: as in
            :class:`~tof_fpn_torch.runtime.TemporalFilter`.

    Shape:
        - depth: (T, C, H, W) float, frames in time order; amplitude: optional (T, 1, H, W).
        - :meth:`run`: the filtered frames and the record ``restarted`` (T,): the pixels the
          motion guard restarted at each frame (a pixel's first valid frame is not counted).

    Example:
        >>> frames = 2.0 + 0.002 * torch.tensor([1.0, -1.0, 1.0, -1.0]).view(4, 1, 1, 1)
        >>> out, rec = TemporalSequence(alpha=0.5, sigma=0.01).run(frames.expand(4, 1, 2, 2))
        >>> round(float(out[-1, 0, 0, 0]), 4), rec["restarted"].tolist()
        (1.9995, [0.0, 0.0, 0.0, 0.0])
    """

    sequence = True
    settings = (
        Setting(
            "alpha",
            float,
            K.TEMPORAL_ALPHA,
            "EMA weight of the new frame",
            low=0.0,
            open_low=True,
            high=1.0,
        ),
        Setting(
            "guard",
            float,
            K.TEMPORAL_GUARD,
            "motion guard, sd of the innovation (inf: none)",
            low=0.0,
            open_low=True,
            finite=False,
        ),
        Setting("sigma", float, K.TEMPORAL_SIGMA, "noise floor, depth units", low=0.0),
        Setting("noise_k", float, 0.0, "k of the noise law k / A (0: not used)", low=0.0),
        Setting("persistence", int, 0, "frames an invalid pixel shows its last estimate", low=0),
    )
    record = (RecordField("restarted", "pixels the motion guard restarted at the frame"),)

    def __init__(
        self,
        alpha: float = K.TEMPORAL_ALPHA,
        guard: float = K.TEMPORAL_GUARD,
        sigma: float = K.TEMPORAL_SIGMA,
        noise_k: float = 0.0,
        persistence: int = 0,
    ) -> None:
        super().__init__()
        self.filter = TemporalFilter(alpha, guard, sigma, noise_k, persistence)
        check_settings(
            type(self),
            alpha=alpha,
            guard=guard,
            sigma=sigma,
            noise_k=noise_k,
            persistence=persistence,
        )

    @property
    def alpha(self) -> float:
        return self.filter.alpha

    @property
    def guard(self) -> float:
        return self.filter.guard

    @property
    def persistence(self) -> int:
        return self.filter.persistence

    __jit_unused_properties__ = ["alpha", "guard", "persistence"]

    def _run(
        self, depth: torch.Tensor, amplitude: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        t = depth.shape[0]
        if t == 0:
            return depth, {"restarted": torch.zeros(0, device=depth.device)}
        c = depth.shape[1]
        state = self.filter.initial_state(depth[:1])
        frames: list[torch.Tensor] = []
        restarted: list[torch.Tensor] = []
        for i in range(t):
            a: torch.Tensor | None = None
            if amplitude is not None:
                a = amplitude[i : i + 1]
            y, new = self.filter(depth[i : i + 1], state, a)
            again = (new[:, c : 2 * c] == 1.0) & (state[:, c : 2 * c] > 0)
            restarted.append(again.flatten(1).sum(1).to(torch.float32))
            frames.append(y)
            state = new
        return torch.cat(frames), {"restarted": torch.cat(restarted)}
