"""``--pattern FILE``: a fixed pattern of ``tof-fpn calibrate``, removed from every frame first
(:class:`~tof_fpn_torch.runtime.FixedPatternCorrection` or
:class:`~tof_fpn_torch.runtime.ComplexPatternCorrection`); the stages after it, and their
measurement on the calibration frames, see what it leaves."""

from __future__ import annotations

from torch import nn

from ...runtime.stage import Setting
from ..pattern_file import load_pattern
from .base import Context, Option, Step

__all__ = ["STEP"]


def _resolve(values: dict) -> None:
    p = values["pattern"]
    if p is not None and (not isinstance(p, str) or not p):
        raise ValueError(f"pattern must be a file name or absent, got {p!r}")


def _build(ctx: Context) -> nn.Module | None:
    path = ctx.config.pattern
    return None if path is None else load_pattern(path)


def _describe(module: nn.Module | None) -> dict:
    return {"pattern": None if module is None else type(module).__name__}


def _phrase(info: dict) -> list[str]:
    return [] if info.get("pattern") is None else [f"fixed pattern ({info['pattern']})"]


STEP = Step(
    name="pattern",
    options=(
        Option(
            Setting("pattern", str, None, "a fixed pattern from tof-fpn calibrate, removed first"),
            "pipeline",
            "pattern",
            path=True,
        ),
    ),
    build=_build,
    describe=_describe,
    phrase=_phrase,
    resolve=_resolve,
)
