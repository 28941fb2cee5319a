r"""Save and load a trained whole model (front end + network) as a weights-only checkpoint.

A checkpoint is a dict of plain types and tensors (loadable with ``torch.load(...,
weights_only=True)``: no pickled code runs): the front end's name, the training
:class:`~tof_fpn_torch.learn.Settings` (network size), the fusion thresholds and the model's
``state_dict``. :func:`load_model` rebuilds the model with :func:`~tof_fpn_torch.learn.make_model`
and loads the weights, so a trained notch comes back with its zeros still held.
``tof-fpn export --model PATH`` exports such a file to TorchScript or ONNX.
"""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

import torch

from .front_ends import FRONT_ENDS, Settings, make_model
from .models import DepthModel

__all__ = ["CHECKPOINT_FORMAT", "load_model", "save_model"]

#: the ``format`` entry of every checkpoint this module writes
CHECKPOINT_FORMAT = "tof_fpn_torch.learn.checkpoint/1"


def save_model(
    path: str | Path,
    model: DepthModel,
    front: str,
    settings: Settings,
    thresholds: tuple[float, float],
) -> Path:
    """Write ``model`` (built by ``make_model(front, thresholds, settings)``) to ``path``."""
    if not isinstance(model, DepthModel):
        raise ValueError(f"model must be a DepthModel, got {type(model).__name__}")
    if front not in FRONT_ENDS:
        raise ValueError(f"front must be one of {FRONT_ENDS}, got {front!r}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().cpu() for k, v in model.state_dict().items()}
    payload = {
        "format": CHECKPOINT_FORMAT,
        "front": front,
        "settings": {
            k: list(v) if isinstance(v, tuple) else v for k, v in asdict(settings).items()
        },
        "thresholds": [float(thresholds[0]), float(thresholds[1])],
        "state_dict": state,
    }
    tmp = path.with_name(path.name + ".part")
    torch.save(payload, tmp)
    tmp.replace(path)
    return path


def load_model(path: str | Path) -> tuple[DepthModel, dict]:
    """The model stored at ``path`` (in eval mode) and the checkpoint's description
    (``front``, ``settings``, ``thresholds``).

    Raises:
        FileNotFoundError: no such file.
        ValueError: the file is not a checkpoint of this format.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no model checkpoint at {path}")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # a TorchScript archive, an arbitrary pickle, a text file ...
        raise ValueError(
            f"{path} is not a model checkpoint written by tof_fpn_torch.learn.save_model "
            f"(or examples/train_front_ends.py): {type(exc).__name__}: {exc}".split("\n")[0]
        ) from None
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        found = payload.get("format") if isinstance(payload, dict) else type(payload).__name__
        raise ValueError(f"{path} is not a {CHECKPOINT_FORMAT} checkpoint (found {found!r})")
    raw = dict(payload["settings"])
    raw["size"] = tuple(raw["size"])
    settings = Settings(**raw)
    thresholds = (float(payload["thresholds"][0]), float(payload["thresholds"][1]))
    model = make_model(payload["front"], thresholds, settings)
    model.load_state_dict(payload["state_dict"])
    model.eval()
    info = {"front": payload["front"], "settings": settings, "thresholds": thresholds}
    return model, info
