"""``tof-fpn calibrate``: a camera's fixed pattern measured once, from recordings of flat walls,
then removed from every frame by ``tof-fpn clean --pattern FILE``.

The frames are read like ``tof-fpn clean`` reads INPUT (every format it takes, camera files
included), in metres; all readable frames of the first frame's size are used. Two domains:

* ``depth`` (:func:`~tof_fpn_torch.analysis.calibrate_fixed_pattern`): per-column and per-row
  offsets of the temporal mean (and per-pixel offsets with ``flat_field``: the wall is a smooth
  surface); applied as :class:`~tof_fpn_torch.runtime.FixedPatternCorrection`;
* ``complex`` (:func:`~tof_fpn_torch.analysis.calibrate_complex_pattern`): read-out offsets added
  to the complex signal ``A exp(j phi)``, which enter the depth as ``1 / A``; needs the modulation
  frequency; applied as :class:`~tof_fpn_torch.runtime.ComplexPatternCorrection`;
* ``scenes`` (:func:`~tof_fpn_torch.analysis.learn_folder_pattern`): the pattern frames of
  different scenes share, learned as ``clean`` learns it (no flat wall needed; the modulation
  frequency, when given, for a read-out part); applied as
  :class:`~tof_fpn_torch.runtime.PatternCorrection`.

A pattern file (``.npz``, :mod:`tof_fpn_torch.io.patterns`) says which it is: :func:`save_pattern` /
:func:`read_pattern` write and read it, :func:`load_pattern` returns the run-time module.
"""

from __future__ import annotations

from pathlib import Path

from ..analysis import (
    ComplexPattern,
    FixedPattern,
    LearnedPattern,
    calibrate_complex_pattern,
    calibrate_fixed_pattern,
    learn_folder_pattern,
)
from .config import CleanConfig
from .pattern_file import load_pattern, read_pattern, save_pattern
from .plan import plan_jobs
from .work import read_jobs

__all__ = ["DOMAINS", "calibrate", "load_pattern", "read_frames", "read_pattern", "save_pattern"]

#: the domains a pattern is calibrated in
DOMAINS = ("depth", "complex", "scenes")


def read_frames(input_path: str, config: CleanConfig, limit: int | None = None):
    """``(depth, amplitude, camera)``: the readable frames of INPUT (a file or a folder, as
    ``tof-fpn clean`` takes it) of the first frame's size, (N, 1, H, W) metres and camera units,
    at most ``limit``; frames with no valid pixel are left out. ``ValueError`` when there are none.
    """
    return read_jobs(plan_jobs(input_path, "."), config, limit)  # the output names are not used


def calibrate(
    input_path: str,
    output: str,
    config: CleanConfig | None = None,
    *,
    domain: str = "depth",
    rows: bool = False,
    flat_field: bool = False,
    modulation_frequency_hz: float | None = None,
) -> FixedPattern | ComplexPattern | LearnedPattern:
    """Calibrate the fixed pattern of the frames of ``input_path`` and save it to ``output``.

    Args:
        input_path: frames of flat walls (a file or a folder; at least 2 frames); for
            ``scenes``, frames of at least 4 different scenes.
        output: the pattern file to write (``.npz``; refused if it exists).
        config: the file options (``height``, ``width``, ``depth_scale``) of :class:`CleanConfig`.
        domain: ``"depth"``, ``"complex"`` or ``"scenes"`` (module docstring).
        rows: complex domain: row offsets too (the depth domain always has them).
        flat_field: depth domain: per-pixel offsets too (the scene is one smooth surface).
        modulation_frequency_hz: complex domain: the camera's modulation frequency (scenes:
            optional, for a read-out part).

    Raises:
        ValueError: a bad argument, an existing ``output``, fewer than 2 frames; for
            ``scenes``, frames from which no pattern could be confirmed (the message says why).
    """
    config = CleanConfig() if config is None else config
    if domain not in DOMAINS:
        raise ValueError(f"domain must be one of {list(DOMAINS)}, got {domain!r}")
    if domain == "complex" and modulation_frequency_hz is None:
        raise ValueError("the complex domain needs the modulation frequency (Hz)")
    if domain == "scenes" and (rows or flat_field):
        raise ValueError("the scenes domain learns columns, rows and pixels itself")
    if domain == "depth" and modulation_frequency_hz is not None:
        raise ValueError("a modulation frequency is for the complex domain (domain='complex')")
    if Path(output).exists():
        raise ValueError(f"{output!r} exists; choose a new file for the pattern")
    depth, amplitude, _ = read_frames(input_path, config)
    if depth.shape[0] < 2:
        raise ValueError(f"a fixed pattern needs >= 2 frames, {input_path!r} has {depth.shape[0]}")
    if domain == "scenes":
        learned = learn_folder_pattern(
            depth, amplitude, modulation_frequency_hz=modulation_frequency_hz
        )
        if learned.pattern is None:
            raise ValueError(learned.summary())
        save_pattern(learned, output)
        return learned
    if domain == "depth":
        pattern = calibrate_fixed_pattern(depth, amplitude, flat_field=flat_field)
    else:
        pattern = calibrate_complex_pattern(depth, amplitude, modulation_frequency_hz, rows=rows)
    save_pattern(pattern, output)
    return pattern
