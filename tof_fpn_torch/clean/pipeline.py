"""The torch side of ``tof-fpn clean``: the registered steps a :class:`CleanConfig` asks for, as
one ordered list of stages.

Each step (:mod:`tof_fpn_torch.clean.steps`: fixed pattern, FPN stage, flying pixels, denoiser,
temporal filter) builds its stage from the configuration, or none; a stage measured on data
(``destripe = "auto"``, ``notch = "data"``, ``fusion = "data"``) is measured on the calibration
frames (frames spread over the camera's files, read by the caller) as the stages before it
leave them, with the builders of :mod:`tof_fpn_torch.build`, and is then fixed for the whole run.
Frame stages run on batches of frames (:meth:`CleanPipeline.forward`); sequence stages (temporal)
run afterwards over the frames of each frame set in order (:meth:`CleanPipeline.run_sequence`).
Every stage reports what it did in its record (:meth:`~tof_fpn_torch.runtime.stage.Stage.run`),
computed in the same pass as its output.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import nn

from .. import denoise as _denoise
from .config import CleanConfig
from .steps import Context, Step, steps

__all__ = [
    "DENOISERS",
    "Calibration",
    "CleanPipeline",
    "build_pipeline",
    "describe",
    "register_denoiser",
    "stage_line",
]

#: the denoiser registry (name -> factory(**options) -> module ``(depth, amplitude) -> depth``):
#: :data:`tof_fpn_torch.denoise.DENOISERS` itself
DENOISERS = _denoise.DENOISERS
#: add a denoiser by name (``denoise = "<name>"``, ``--denoise <name>``):
#: :func:`tof_fpn_torch.denoise.register`
register_denoiser = _denoise.register


@dataclass
class Calibration:
    """The frames data-driven stages are measured on: depth (N, 1, H, W) metres, amplitude
    (N, 1, H, W) camera units, and the camera profile the files name (None: not said)."""

    depth: torch.Tensor
    amplitude: torch.Tensor
    camera: str | None = None


class CleanPipeline(nn.Module):
    """The built stages in order, each under its step's name (an empty pipeline returns its
    input).

    Shape: depth and amplitude (B, 1, H, W) float, metres and camera units; output (B, 1, H, W),
    invalid pixels unchanged (every stage keeps them). Runs without autograd.

    Attributes:
        stages: the frame stages (``nn.ModuleDict``, in order).
        sequence: the sequence stages (``nn.ModuleDict``, in order), run by :meth:`run_sequence`.
        calibration: what the data-driven stages were measured on (``frames``, ``camera``), or
            None.
    """

    def __init__(self, stages: list[tuple[str, nn.Module]] | None = None) -> None:
        super().__init__()
        by_scope: dict[str, list] = {"frame": [], "sequence": []}
        registered = {s.name: s for s in steps()}
        for name, module in stages or []:
            scope = registered[name].scope if name in registered else "frame"
            by_scope[scope].append((name, module))
        self.stages = nn.ModuleDict(dict(by_scope["frame"]))
        self.sequence = nn.ModuleDict(dict(by_scope["sequence"]))
        self.calibration: dict | None = None
        #: step name -> the per-pixel record fields to keep (written beside each output)
        self.keep_maps: dict[str, tuple[str, ...]] = {}
        #: step name -> what its builder said (found, or why nothing was built)
        self.notes: dict[str, str] = {}

    def stage(self, name: str) -> nn.Module | None:
        """The stage of the step ``name``, or None when this run has none."""
        if name in self.stages:
            return self.stages[name]
        return self.sequence[name] if name in self.sequence else None

    @torch.no_grad()
    def forward(
        self, depth: torch.Tensor, amplitude: torch.Tensor
    ) -> tuple[torch.Tensor, dict[str, dict[str, torch.Tensor]]]:
        """The frame stages in order: the cleaned frames and each stage's record by step name."""
        y = depth
        records: dict[str, dict[str, torch.Tensor]] = {}
        for name, stage in self.stages.items():
            y, records[name] = stage.run(y, amplitude)
        return y, records

    @torch.no_grad()
    def run_sequence(self, depth: torch.Tensor, amplitude: torch.Tensor, timestamps=None):
        """The sequence stages over the (T, 1, H, W) frames of one frame set in order:
        ``(frames, {step name: record})``."""
        registered = {s.name: s for s in steps()}
        records = {}
        for name, stage in self.sequence.items():
            depth, records[name] = registered[name].run_sequence(
                stage, depth, amplitude, timestamps
            )
        return depth, records


def build_pipeline(
    config: CleanConfig, calibration: Callable[[], Calibration] | None = None
) -> CleanPipeline:
    """The :class:`CleanPipeline` of ``config``: each registered step's stage, in order.

    Args:
        config: the stages and settings.
        calibration: called (once, only when a stage is measured on data or the camera is asked
            for) for the :class:`Calibration` frames; a later step sees them as the stages
            before it leave them.

    Raises:
        ValueError: a data-driven stage without ``calibration``, or a setting the builders refuse.
    """
    cache: dict = {}
    built: list[tuple[str, nn.Module]] = []

    def frames_for(upto: int) -> Calibration:
        if calibration is None:
            raise ValueError(
                "this configuration measures a stage on data (destripe = 'auto', notch = 'data' "
                "or fusion = 'data') or uses the files' camera, but no calibration frames were "
                "given"
            )
        if "raw" not in cache:
            cache["raw"] = calibration()
        c = cache["raw"]
        for name, stage in built[:upto]:  # the later stages see what the earlier ones leave
            try:
                with torch.no_grad():
                    c = Calibration(stage(c.depth, c.amplitude), c.amplitude, c.camera)
            except ValueError as exc:
                raise ValueError(f"{_failed_on_calibration(name, config)}: {exc}") from None
        return c

    measured = False
    notes: dict[str, str] = {}
    for step in steps():
        upto = len(built)
        ctx = Context(config, lambda upto=upto: frames_for(upto), built=dict(built))
        module = step.build(ctx)
        measured = measured or ctx.measured
        if module is not None:
            built.append((step.name, module))
        if ctx.notes:
            notes[step.name] = "; ".join(ctx.notes)
    pipeline = CleanPipeline(built)
    pipeline.notes = notes
    for step in steps():
        if step.keep_maps is not None and pipeline.stage(step.name) is not None:
            pipeline.keep_maps[step.name] = tuple(step.keep_maps(config))
    if measured and "raw" in cache:
        c = cache["raw"]
        pipeline.calibration = {"frames": int(c.depth.shape[0]), "camera": c.camera}
    pipeline.eval()
    return pipeline


def _failed_on_calibration(name: str, config: CleanConfig) -> str:
    """How an error of the stage ``name`` on the calibration frames is prefixed."""
    return f"pattern {config.pattern}" if name == "pattern" else f"stage {name}"


def describe(pipeline: CleanPipeline) -> dict:
    """What the pipeline does, as plain values (recorded in the manifest): each registered
    step's description (None or off where this run has no stage of it) and the calibration."""
    out: dict = {}
    for step in steps():
        out.update(step.describe(pipeline.stage(step.name)))
    out["calibration"] = pipeline.calibration
    if pipeline.notes:
        out["notes"] = dict(pipeline.notes)
    return out


def stage_line(info: dict, stage: str, registered: list[Step] | None = None) -> str:
    """One line saying what the pipeline of :func:`describe` does (what the command prints)."""
    registered = registered or steps()
    parts = [p for step in registered for p in step.phrase(info)]
    notes = info.get("notes") or {}
    said = "".join(f"; {notes[step.name]}" for step in registered if step.name in notes)
    calib = info.get("calibration")
    source = ""
    if calib is not None:
        camera = f", camera {calib['camera']}" if calib.get("camera") else ""
        source = f", measured on {calib['frames']} calibration frame(s){camera}"
    if not parts:
        nothing = (
            "no periodic stripe or broadband offset it could remove with confidence"
            if calib
            else "every stage off"
        )
        return (
            f"stage {stage}{source}: nothing to do ({nothing}); the outputs equal the inputs{said}"
        )
    return f"stage {stage}{source}: " + "; ".join(parts) + said
