"""The front ends a learned depth network can sit behind, and the models built from them (what a
checkpoint needs to rebuild a trained model; the training experiment that compares them is
``examples/train_front_ends.py``).

Front ends (:data:`FRONT_ENDS`):

* ``none``: the network alone;
* ``fixed``: the FPN stage as designed (``suppression_from_design``: unit-DC notch and fusion,
  the stripe gate off: the network then sees one kind of input whatever the frame);
* ``trainable``: the same stage trained jointly with the network, its notch zeros held
  (``trainable_suppression``);
* ``fixed+nlm``: the fixed stage, then amplitude-aware NLM (``sigma = k / A``), then the network.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from ..build import suppression_from_design, trainable_suppression
from ..denoise import NonLocalMeans
from .models import DepthModel, DnCNN

__all__ = ["FRONT_ENDS", "Settings", "make_model"]

FRONT_ENDS: tuple[str, ...] = ("none", "fixed", "trainable", "fixed+nlm")
#: the stripe gate of the fixed front ends (off: see the module docstring)
GATE = False
#: search half-width of the NLM in ``fixed+nlm`` (7 x 7 windows: NLM is most of that run's time)
NLM_SEARCH = 3


@dataclass(frozen=True)
class Settings:
    """One training run: ``steps`` Adam steps (learning rate ``lr``, cosine decay to 0) of
    ``batch`` frames of ``size``, drawn by ``workers`` DataLoader workers; the network is
    ``DnCNN(layers, channels)``."""

    steps: int = 720
    batch: int = 8
    size: tuple[int, int] = (48, 48)
    lr: float = 1e-3
    workers: int = 0
    layers: int = 6
    channels: int = 16


class _StageThenDenoiser(nn.Module):
    """``denoiser(stage(depth, amplitude), amplitude)``."""

    def __init__(self, stage: nn.Module, denoiser: nn.Module) -> None:
        super().__init__()
        self.stage = stage
        self.denoiser = denoiser

    def forward(self, depth: torch.Tensor, amplitude: torch.Tensor) -> torch.Tensor:
        return self.denoiser(self.stage(depth, amplitude), amplitude)


def make_model(front: str, thresholds: tuple[float, float], settings: Settings) -> DepthModel:
    """The network behind the named front end."""
    if front not in FRONT_ENDS:
        raise ValueError(f"front must be one of {FRONT_ENDS}, got {front!r}")
    low, high = thresholds
    net = DnCNN(settings.layers, settings.channels)
    if front == "none":
        return DepthModel(net)
    if front == "trainable":
        return DepthModel(net, trainable_suppression(low=low, high=high, gate=False))
    stage = suppression_from_design(low=low, high=high, gate=GATE)
    if front == "fixed":
        return DepthModel(net, stage)
    return DepthModel(
        net, _StageThenDenoiser(stage, NonLocalMeans(patch_size=5, patch_distance=NLM_SEARCH))
    )
