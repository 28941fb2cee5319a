"""The options of a ``tof-fpn clean`` run that belong to no step: files, batches, calibration."""

from __future__ import annotations

from ...runtime.stage import Setting
from .base import Option

__all__ = ["BATCH", "CALIBRATION_FRAMES", "FILE_OPTIONS", "ROUNDING"]

#: Files per group (``batch``): what a worker or a Ray task loads, computes and writes at a time.
#: Every frame is computed alone (:mod:`tof_fpn_torch.clean.work`), so it does not change the
#: output bytes.
BATCH: int = 8
#: Frames (from files spread evenly over the camera's) on which ``auto`` / ``data`` stages are
#: measured when the run starts (``calibration_frames``).
CALIBRATION_FRAMES: int = 8
#: integer outputs: how a corrected depth is rounded to the stored unit
ROUNDING: tuple[str, ...] = ("dither", "nearest")

_POSITIVE = dict(low=0.0, open_low=True)

FILE_OPTIONS: tuple[Option, ...] = (
    Option(
        Setting(
            "calibration_frames",
            int,
            CALIBRATION_FRAMES,
            "frames measured by data stages",
            low=1,
        ),
        "calibration",
        "frames",
    ),
    Option(
        Setting("batch", int, BATCH, "files per group (a worker's unit of work)", low=1),
        "files",
        "batch",
    ),
    Option(
        Setting("depth_scale", float, None, "metres per stored depth unit", **_POSITIVE),
        "files",
        "depth_scale",
    ),
    Option(
        Setting("height", int, None, "rows of raw .bin / .raw frames", low=1), "files", "height"
    ),
    Option(
        Setting("width", int, None, "columns of raw .bin / .raw frames", low=1), "files", "width"
    ),
    Option(
        Setting(
            "rounding",
            str,
            "dither",
            "integer outputs: dither (sub-unit corrections survive in the mean) or nearest",
            choices=ROUNDING,
        ),
        "files",
        "rounding",
    ),
    Option(
        Setting(
            "output_scale",
            float,
            None,
            "integer outputs: metres per stored unit, e.g. 0.0001 (default: the input's)",
            **_POSITIVE,
        ),
        "files",
        "output_scale",
    ),
)
