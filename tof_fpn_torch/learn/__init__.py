"""The FPN stage in front of learned depth networks: simulated training data, a compact network,
whole models that keep invalid pixels, checkpoints (the top layer).

May import every layer below it (runtime, build, denoise, analysis, sim, design, cameras) and
matplotlib through :mod:`tof_fpn_torch.plotting`. Nothing imports it but the CLI. The training
experiment that compares four front ends is an example beside the package
(``examples/train_front_ends.py``, ``examples/front_ends.py``).

- :mod:`.dataset`: :class:`SimulatedFrames`, an ``IterableDataset`` with domain randomisation.
- :mod:`.models`: :class:`DnCNN`, :class:`DepthModel` (front end + network, invalid pixels kept).
- :mod:`.front_ends`: :data:`FRONT_ENDS`, :class:`Settings`, :func:`make_model` (the models a
  checkpoint rebuilds).
- :mod:`.checkpoint`: :func:`save_model`, :func:`load_model` (weights-only files).
"""

from .checkpoint import load_model, save_model
from .dataset import Ranges, SimulatedFrames, draw_sample
from .front_ends import FRONT_ENDS, Settings, make_model
from .models import DepthModel, DnCNN

__all__ = [
    "FRONT_ENDS",
    "Settings",
    "make_model",
    "DepthModel",
    "DnCNN",
    "Ranges",
    "SimulatedFrames",
    "draw_sample",
    "load_model",
    "save_model",
]
