"""Which files of a ``tof-fpn clean`` run come from one camera: :func:`camera_groups`.

A stage measured on data (``--stage auto``) is measured on one camera's frames and is right for
that camera only: the stripes of another sensor are elsewhere, or absent. So a run splits its jobs
into camera groups and measures and runs one pipeline per group (:func:`build_cameras`). A job's
group is named by a :func:`camera_key` found without decoding any frame:

* the file format (:func:`~tof_fpn_torch.io.formats.format_for`): PNG, TIFF, ``.npy``, raw,
  ``.npz``, HDF5, the ADI vendor files;
* the frame size its header states (:func:`~tof_fpn_torch.io.headers.frame_sizes`): a PNG's
  header (not decoded), a TIFF's first page header, a ``.npy``'s header (in an ``.npz``: its
  ``depth.npy``), an HDF5 file's depth datasets (shapes only), an ADI vendor file's name, raw
  files the configured ``height`` x ``width``;
* a recording container (an ``.mkv``, a bag) is one camera by itself: one group per file.

A key reads ``"<format> <H>x<W>"`` (``"png 480x640"``), ``"<format> <file>"`` for a container
(``"mkv cam/take.mkv"``) and ``"<format> size unknown"`` when the header cannot be read (such a file
fails when it is read, with its reason).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from ..io.formats import RECORDING, format_for
from ..io.headers import frame_sizes
from ..runtime import FixedPatternCorrection, PatternCorrection
from .config import CleanConfig
from .measure import finite_values
from .pipeline import Calibration, CleanPipeline, build_pipeline, describe, stage_line
from .plan import Job
from .work import NoFramesError, read_jobs

__all__ = [
    "learned_patterns",
    "UNKNOWN_SIZE",
    "UNMEASURED",
    "Camera",
    "build_cameras",
    "camera_groups",
    "camera_key",
    "stage_lines",
    "start_fields",
]

#: the size part of a key when the file's header cannot be read
UNKNOWN_SIZE = "size unknown"


def camera_key(job: Job, config: CleanConfig) -> str:
    """The camera group of ``job`` (module docstring), from its file format and the frame size
    its headers state; no frame is decoded. ``config``: the ``height`` / ``width`` of raw
    files."""
    fmt = format_for(job.depth)
    if fmt is None:  # not a format of the table: the planner does not make such jobs
        return f"{os.path.splitext(job.depth)[1].lower() or 'file'} {UNKNOWN_SIZE}"
    if fmt.holds == RECORDING:
        return f"{fmt.name} {job.name}"
    sizes = frame_sizes(job.depth, height=config.height, width=config.width)
    if not sizes:
        return f"{fmt.name} {UNKNOWN_SIZE}"
    return f"{fmt.name} " + "+".join(f"{h}x{w}" for h, w in sizes)


def camera_groups(jobs: list[Job], config: CleanConfig) -> list[tuple[str, list[Job]]]:
    """The runnable jobs (those without ``error``) grouped by :func:`camera_key`:
    ``[(key, jobs)]``, the jobs of a group in their order in ``jobs``, the groups in the order of
    their first job. Each group is one camera: a data-driven stage is measured on its own frames
    and runs on its own files."""
    groups: dict[str, list[Job]] = {}
    for job in jobs:
        if job.error is None:
            groups.setdefault(camera_key(job, config), []).append(job)
    return list(groups.items())


def _calibration(jobs, config: CleanConfig) -> Calibration:
    """``calibration_frames`` readable frames (of the first readable frame's shape, frames with
    no valid pixel left out) from files spread evenly over ``jobs`` (the first, the last and
    between: a camera's folder shows many scenes, its first files often one), then from the
    others in order where those are not enough; and the camera the files name."""
    n = config.calibration_frames
    if len(jobs) > n > 1:
        step = (len(jobs) - 1) / (n - 1)
        chosen = sorted({round(i * step) for i in range(n)})
        order = [jobs[i] for i in chosen] + [j for i, j in enumerate(jobs) if i not in chosen]
    else:
        order = list(jobs)
    try:
        return Calibration(*read_jobs(order, config, n))
    except NoFramesError as exc:  # every file's reason, in file order
        rank = {j.name: i for i, j in enumerate(jobs)}
        raise NoFramesError(sorted(exc.failures, key=lambda f: rank.get(f[0], -1))) from None


#: a camera group whose files hold no frame to measure on (others do): it gets no stage
UNMEASURED = (
    "no readable frame with a valid pixel to measure on; its frames pass as they are "
    "(files that cannot be read fail)"
)


@dataclass
class Camera:
    """One camera group of a run (:func:`camera_groups`) and its pipeline.

    Attributes:
        key: the group's camera key (None: the run has no runnable file).
        jobs: its runnable jobs, in file order.
        pipeline: the stages its files run through, measured on its own frames.
        unmeasured: why nothing was measured (:data:`UNMEASURED`), else None.
    """

    key: str | None
    jobs: list
    pipeline: CleanPipeline
    unmeasured: str | None = None

    @property
    def stages_off(self) -> bool:
        """No stage and nothing measured: every stage switched off."""
        p = self.pipeline
        return p.calibration is None and not [*p.stages, *p.sequence]

    def record(self) -> dict:
        """The group in the manifest's ``start`` record: ``key``, ``files`` (how many),
        ``pipeline`` (:func:`~.pipeline.describe`), ``note`` when nothing was measured."""
        rec = {"key": self.key, "files": len(self.jobs), "pipeline": describe(self.pipeline)}
        if self.unmeasured:
            rec["note"] = self.unmeasured
        return finite_values(rec)


def build_cameras(jobs, config: CleanConfig) -> list[Camera]:
    """One :class:`Camera` per camera group of ``jobs``, each pipeline measured on readable
    frames of its own files, spread over them (:func:`_calibration`). With several groups, a group none of whose files has a
    frame to measure on gets no stage (its frames pass as they are, :data:`UNMEASURED`).
    :class:`~.work.NoFramesError`, with every file's reason in file order (the jobs that failed
    planning too), when no group has one."""
    groups = camera_groups(jobs, config)
    if len(groups) <= 1:
        key, members = groups[0] if groups else (None, [])
        return [Camera(key, members, build_pipeline(config, lambda: _calibration(jobs, config)))]
    cameras, failures = [], []
    for key, members in groups:
        try:
            pipeline = build_pipeline(config, lambda m=members: _calibration(m, config))
        except NoFramesError as exc:
            failures += exc.failures
            cameras.append(Camera(key, members, CleanPipeline(), UNMEASURED))
        else:
            cameras.append(Camera(key, members, pipeline))
    if all(c.unmeasured for c in cameras):
        failures += [(j.name, j.error) for j in jobs if j.error is not None]
        order = {j.name: i for i, j in enumerate(jobs)}
        raise NoFramesError(sorted(failures, key=lambda f: order.get(f[0], len(order))))
    return cameras


def stage_lines(cameras: list[Camera], stage: str) -> str:
    """What the command prints of the stages: one camera's :func:`~.pipeline.stage_line`, or,
    for several cameras, one line per camera, ``camera <key> (<n> file(s)): <its stage line>``."""
    if len(cameras) == 1:
        return stage_line(describe(cameras[0].pipeline), stage)
    lines = []
    for c in cameras:
        line = (
            f"stage {stage}: nothing measured ({c.unmeasured})"
            if c.unmeasured
            else stage_line(describe(c.pipeline), stage)
        )
        lines.append(f"camera {c.key} ({len(c.jobs)} file(s)): {line}")
    return "\n".join(lines)


def start_fields(cameras: list[Camera]) -> dict:
    """The manifest's ``start`` record fields of the cameras: ``cameras`` (each
    :meth:`Camera.record`) and ``pipeline``, the one camera's (None with several)."""
    one = finite_values(describe(cameras[0].pipeline)) if len(cameras) == 1 else None
    return {"pipeline": one, "cameras": [c.record() for c in cameras if c.key is not None]}


def learned_patterns(cameras: list[Camera]) -> dict:
    """File name -> the (H, W) offsets in mm its camera's pipeline removes first (a learned
    :class:`~tof_fpn_torch.runtime.PatternCorrection`'s offsets), for the figure."""
    out = {}
    for cam in cameras:
        stage = cam.pipeline.stage("pattern")
        if not isinstance(stage, PatternCorrection):
            continue
        for part in stage.corrections:
            if isinstance(part, FixedPatternCorrection):
                offsets = part.offset.double().cpu() * 1e3  # (H, W): learned with rows
                out.update({job.name: offsets.numpy() for job in cam.jobs})
                break
    return out
