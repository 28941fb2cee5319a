r"""Train a compact depth denoiser behind four front ends on simulated frames, and evaluate it.

Front ends (:data:`FRONT_ENDS`):

* ``none``: the network alone;
* ``fixed``: the FPN stage as designed (``suppression_from_design``: unit-DC notch and fusion,
  the stripe gate off: see below);
* ``trainable``: the same stage trained jointly with the network, its notch zeros held
  (``trainable_suppression``);
* ``fixed+nlm``: the fixed stage, then amplitude-aware NLM (``sigma = k / A``), then the network.

The fusion thresholds of the stage are measured once on a calibration batch of the simulator's own
frames (:func:`~tof_fpn_torch.build.fusion_from_noise`, the paper's thresholds carried over by the
noise law): the simulator's amplitudes are DN, not CamCube units. The stripe gate (which leaves a frame without detected periodic stripes unchanged)
is off in the learned front ends, so that the network sees one kind of input whatever the frame
(with the gate on it sees filtered and raw frames mixed; measured: no significant difference at
the default budget, ``docs/learn.md``).
Everything is seeded; ``examples/train_front_ends.py`` runs the experiment. The front ends and
the models are the package's (:mod:`tof_fpn_torch.learn.front_ends`); this is the training loop.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import torch
from torch import nn
from torch.utils.data import DataLoader

from tof_fpn_torch.analysis.metrics import psnr
from tof_fpn_torch.build import fusion_from_noise
from tof_fpn_torch.learn.dataset import SimulatedFrames, draw_sample
from tof_fpn_torch.learn.front_ends import FRONT_ENDS, Settings, make_model
from tof_fpn_torch.learn.models import DepthModel

__all__ = ["FRONT_ENDS", "Settings", "evaluate", "fusion_thresholds", "make_model", "train"]

#: seed of the calibration batch and of the held-out evaluation stream (never trained on)
CALIBRATION_SEED = 777
EVALUATION_SEED = 10_000


def fusion_thresholds(size: tuple[int, int] = (96, 96), frames: int = 16) -> tuple[float, float]:
    """Fusion ``(low, high)`` measured on ``frames`` calibration frames of the simulator."""
    items = [draw_sample(CALIBRATION_SEED, i, size) for i in range(frames)]
    depth = torch.stack([it[0] for it in items])
    amp = torch.stack([it[1] for it in items])
    fusion = fusion_from_noise(depth, amp)
    return fusion.low, fusion.high


@dataclass
class Trained:
    """A trained model and its curve (loss per step, seconds)."""

    model: DepthModel
    losses: list[float] = field(default_factory=list)
    seconds: float = 0.0


def train(front: str, seed: int, settings: Settings, thresholds: tuple[float, float]) -> Trained:
    """Train the named front end + network from scratch on the stream ``seed``."""
    torch.manual_seed(seed)
    model = make_model(front, thresholds, settings)
    # the front end starts from a design: it trains 10x slower than the network starting from 0
    front_params = [] if model.front_end is None else list(model.front_end.parameters())
    groups = [{"params": list(model.network.parameters()), "lr": settings.lr}]
    if front_params:
        groups.append({"params": front_params, "lr": 0.1 * settings.lr})
    opt = torch.optim.Adam(groups)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(opt, max(1, settings.steps))
    data = SimulatedFrames(settings.size, seed=seed, length=settings.steps * settings.batch)
    loader = DataLoader(data, batch_size=settings.batch, num_workers=settings.workers)
    out = Trained(model)
    t0 = time.perf_counter()
    model.train()
    for depth, amp, target, valid in loader:
        pred = model(depth, amp)
        err = torch.where(valid, pred - target, torch.zeros_like(pred))
        loss = err.pow(2).sum() / valid.sum().clamp_min(1)
        opt.zero_grad()
        loss.backward()
        opt.step()
        schedule.step()
        out.losses.append(float(loss.detach()))
    out.seconds = time.perf_counter() - t0
    model.eval()
    return out


def evaluate(model: nn.Module, frames: int, size: tuple[int, int], low_threshold: float) -> dict:
    """PSNR (eq. 9) of the model on ``frames`` held-out simulated frames, over all valid pixels
    and over the low-sensing ones (amplitude below ``low_threshold``, the fusion's ``high``:
    relative depth noise above 0.8 %), with the input's for reference (means of dB)."""
    rows = {"model": [], "input": [], "model_low": [], "input_low": [], "low_share": []}
    with torch.no_grad():
        for i in range(frames):
            depth, amp, target, valid, _ = draw_sample(EVALUATION_SEED, i, size)
            depth, amp, target, valid = (t.unsqueeze(0) for t in (depth, amp, target, valid))
            pred = model(depth, amp)
            low = valid & (amp < low_threshold)
            rows["model"].append(float(psnr(pred, target, valid)))
            rows["input"].append(float(psnr(depth, target, valid)))
            if bool(low.any()):
                rows["model_low"].append(float(psnr(pred, target, low)))
                rows["input_low"].append(float(psnr(depth, target, low)))
            rows["low_share"].append(float(low.sum() / valid.sum().clamp_min(1)))
    return {k: sum(v) / len(v) if v else math.nan for k, v in rows.items()}
