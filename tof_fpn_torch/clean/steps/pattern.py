"""The camera's fixed pattern, removed from every frame first: ``--pattern FILE`` (a pattern of
``tof-fpn calibrate``, :class:`~tof_fpn_torch.runtime.FixedPatternCorrection` or
:class:`~tof_fpn_torch.runtime.ComplexPatternCorrection`), else (``learn``, the default) the
pattern the folder's own frames share, learned from the calibration frames of different scenes
(:func:`~tof_fpn_torch.analysis.learn_folder_pattern`; only the parts two halves of the scenes
confirm, nothing for a still scene or a single frame, and the stage line says which). The stages
after it, and their measurement on the calibration frames, see what it leaves."""

from __future__ import annotations

import json

import torch
from torch import nn

from ...analysis.folder_pattern import learn_folder_pattern
from ...runtime import PatternCorrection
from ...runtime.stage import Setting
from ..errors import NoFramesError
from ..pattern_file import load_pattern
from .base import Context, Option, Step

__all__ = ["STEP"]


def _resolve(values: dict) -> None:
    p = values["pattern"]
    if p is not None and (not isinstance(p, str) or not p):
        raise ValueError(f"pattern must be a file name or absent, got {p!r}")
    if values["learn"] is None:  # the stage preset's: auto learns, paper is the paper's stage
        values["learn"] = values["stage"] == "auto"


def _replace(old: dict, changes: dict) -> None:
    """A new ``stage`` takes its preset's ``learn`` (unless it was chosen)."""
    if "stage" in changes and changes["stage"] != old["stage"]:
        changes.setdefault("learn", None)


def _build(ctx: Context) -> nn.Module | None:
    path = ctx.config.pattern
    given = None if path is None else load_pattern(path)
    if isinstance(given, PatternCorrection):  # a learned pattern saved by tof-fpn calibrate
        given.source = "file"
    if not ctx.config.learn:
        return given
    try:
        c = ctx.frames()
    except NoFramesError as exc:
        ctx.note(f"no fixed pattern learned: {exc}")
        return given
    except ValueError:  # a pipeline built without calibration frames
        ctx.note("no fixed pattern learned: no calibration frames were given")
        return given
    depth = c.depth
    if given is not None:  # learn what the given pattern leaves
        try:
            with torch.no_grad():
                depth = given(depth, c.amplitude)
        except ValueError as exc:
            raise ValueError(f"pattern {path}: {exc}") from None
    learned = learn_folder_pattern(depth, c.amplitude)
    ctx.note(learned.summary())
    if learned.pattern is None:
        return given
    module = learned.module()
    if given is None:
        return module
    return PatternCorrection(
        [given, *module.corrections], source="file+learned", learned=module.learned
    )


def _describe(module: nn.Module | None) -> dict:
    if module is None:
        return {"pattern": None}
    if isinstance(module, PatternCorrection):
        out = {"pattern": module.source}
        if module.learned:
            out["learned"] = json.loads(module.learned)
        return out
    return {"pattern": type(module).__name__}


def _phrase(info: dict) -> list[str]:
    if info.get("pattern") is None:
        return []
    if info["pattern"] == "learned":
        return ["the fixed pattern the frames share"]
    if info["pattern"] == "file":
        return ["the pattern file (learned from scenes)"]
    if info["pattern"] == "file+learned":
        return ["the pattern file, then the fixed pattern the frames still share"]
    return [f"fixed pattern ({info['pattern']})"]


def _file_record(frames: list[dict]) -> dict | None:
    applied = [f["applied"] for f in frames if "applied" in f]
    if not applied:
        return None
    change = [f["roughness_change"] for f in frames if "roughness_change" in f]
    return {
        "applied": int(sum(a > 0.5 for a in applied)),
        "frames": len(applied),
        "roughness_change": round(sum(change) / len(change), 5),
    }


def _summary(records: list[dict]) -> list[str]:
    reports = [r["report"] for r in records if r.get("report")]
    counts = [r["pattern"] for r in reports if r.get("pattern")]
    if not counts:
        return []
    applied, frames = sum(c["applied"] for c in counts), sum(c["frames"] for c in counts)
    line = f"fixed pattern removed from {applied} of {frames} frame(s)"
    if applied < frames:
        line += f"; {frames - applied} left as they were (it did not make them smoother)"
    return [line]


STEP = Step(
    name="pattern",
    options=(
        Option(
            Setting("pattern", str, None, "a fixed pattern from tof-fpn calibrate, removed first"),
            "pipeline",
            "pattern",
            path=True,
        ),
        Option(
            Setting(
                "learn",
                bool,
                None,
                "learn the fixed pattern the frames share, without --pattern (default: with "
                "--stage auto)",
            ),
            "pipeline",
            "learn",
        ),
    ),
    build=_build,
    describe=_describe,
    phrase=_phrase,
    resolve=_resolve,
    on_replace=_replace,
    file_record=_file_record,
    summary=_summary,
)
