"""The FPN stage in front of learned depth networks: simulated training data, a compact network,
training and evaluation with four front ends (the top layer, beside the experiments).

May import every layer below it (runtime, build, denoise, analysis, sim, design, cameras) and
matplotlib through :mod:`tof_fpn_torch.plotting`. Nothing imports it but the scripts and the CLI.

- :mod:`.dataset`: :class:`SimulatedFrames`, an ``IterableDataset`` with domain randomisation.
- :mod:`.models`: :class:`DnCNN`, :class:`DepthModel` (front end + network, invalid pixels kept).
- :mod:`.train`: :func:`train`, :func:`evaluate`, the front ends.
- :mod:`.checkpoint`: :func:`save_model`, :func:`load_model` (weights-only files).
"""

from .checkpoint import load_model, save_model
from .dataset import Ranges, SimulatedFrames, draw_sample
from .models import DepthModel, DnCNN
from .train import FRONT_ENDS, Settings, evaluate, fusion_thresholds, make_model, train

__all__ = [
    "FRONT_ENDS",
    "DepthModel",
    "DnCNN",
    "Ranges",
    "Settings",
    "SimulatedFrames",
    "draw_sample",
    "evaluate",
    "fusion_thresholds",
    "load_model",
    "make_model",
    "save_model",
    "train",
]
