"""``--learn-pattern``: the camera's fixed pattern learned from the folder's own frames of
different scenes (:func:`~tof_fpn_torch.analysis.folder_pattern.learn_fixed_pattern`), removed
from every frame before the FPN stage; only the parts that held-out scenes confirm, and nothing
when the calibration frames show too few distinct scenes (a still camera), which the stage line
says. Off by default. Frames of another size than the calibration frames' fail with the reason.
"""

from __future__ import annotations

import math

from torch import nn

from ...analysis.folder_pattern import learn_fixed_pattern
from ...runtime import FixedPatternCorrection
from ...runtime.stage import Setting
from .base import Context, Option, Step

__all__ = ["STEP"]


def _build(ctx: Context) -> nn.Module | None:
    if not ctx.config.learn_pattern:
        return None
    frames = ctx.frames()
    found = learn_fixed_pattern(frames.depth, frames.amplitude)
    ctx.note(f"learned pattern: {found.reason}")
    return None if found.pattern is None else found.pattern.module()


def _describe(module: nn.Module | None) -> dict:
    if module is None:
        return {"learned_pattern": None}
    assert isinstance(module, FixedPatternCorrection)
    offset = module.offset
    rms = math.sqrt(float(offset.square().mean()))
    return {
        "learned_pattern": {"height": module.height, "width": module.width, "rms_mm": 1e3 * rms}
    }


STEP = Step(
    name="learned",
    options=(
        Option(
            Setting(
                "learn_pattern",
                bool,
                None,
                "learn the camera's fixed pattern from the calibration frames of different scenes "
                "(held-out scenes confirm it) and remove it first",
            ),
            "pipeline",
            "learn_pattern",
        ),
    ),
    build=_build,
    describe=_describe,
)
