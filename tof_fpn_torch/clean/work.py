"""The three steps of ``tof-fpn clean`` on one group of jobs, shared by the local and Ray engines:
:func:`load_group` (decode), :func:`compute_group` (the torch pipeline), :func:`write_group`
(encode, write to temporary names, rename). Their inputs and outputs are plain picklable objects,
so each step can run in another process (``DataLoader`` workers, Ray tasks and actors).

Every frame runs through the frame stages alone, one frame per call: batched torch kernels
(convolutions, matrix products, reductions over the batch) differ in the last bits between batch
sizes and between a frame's positions in a batch, so a frame computed with others would depend on
which frames it met. Alone, a frame's cleaned depth depends on that frame and the pipeline only:
the same input gives the same output bytes whatever ``batch`` (files per group), ``workers`` and
engine, resumed or not. A resumed run reads and computes only its unfinished files.

Failures are per file: a file that cannot be read, decoded, computed or written gets a
``failed`` record with the reason and leaves nothing under its output names (temporary files are
removed); the other files of the group go on.

Frames no stage can work on pass through as they are: frames without a valid pixel (counted in
the record's ``empty_frames``) and frames one pixel wide or high (:func:`~.measure.too_thin`;
the record's ``note`` says so, :data:`THIN_NOTE`).
"""

from __future__ import annotations

import os
import shutil
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from ..io import FormatError, MissingExtraError
from ..io.encode import encode_depth
from ..io.stored import FrameSet, frame_set_tensors, read_frame_sets, write_like
from ..runtime import valid_mask
from .config import CleanConfig
from .errors import NoFramesError
from .manifest import input_identity, now
from .measure import file_report, finite_values, too_thin
from .plan import Job, temporary
from .steps import steps

__all__ = [
    "THIN_NOTE",
    "Loaded",
    "NoFramesError",
    "compute_group",
    "load_group",
    "read_jobs",
    "reason",
    "write_group",
]

#: the ``note`` of a file whose frames are one pixel wide or high (copied as they are)
THIN_NOTE = "1-pixel-wide frame: copied"


@dataclass
class Loaded:
    """One job after :func:`load_group` (and :func:`compute_group`)."""

    job: Job
    sets: list[FrameSet] | None = None
    tensors: list[tuple[torch.Tensor, torch.Tensor]] | None = None
    cleaned: list[torch.Tensor] | None = None
    #: per frame set, per frame: {step: {record field: value}} of the frame stages
    records: list[list[dict]] | None = None
    #: per sequence step: its record of each frame set
    sequence: dict[str, list[dict]] | None = None
    #: ``<step>_<field>`` -> per frame set, the (frames, 1, H, W) map kept (pipeline.keep_maps)
    maps: dict[str, list[torch.Tensor]] | None = None
    empty: int = 0
    #: frames one pixel wide or high (:func:`~.measure.too_thin`): copied as they are
    thin: int = 0
    identity: dict | None = None
    error: str | None = None
    seconds: dict = field(default_factory=lambda: {"read": 0.0, "compute": 0.0, "write": 0.0})


def reason(exc: BaseException) -> str:
    """One line: the message of our own errors (and of a missing optional extra, which names
    what to install), the type and message of anything else."""
    if isinstance(exc, (FormatError, ValueError, FileNotFoundError, MissingExtraError)):
        text = str(exc)
    else:
        text = f"{type(exc).__name__}: {exc}"
    return " ".join(text.split())


def load_group(jobs: list[Job], todo: set[str], config: CleanConfig) -> list[Loaded]:
    """Read and decode the jobs of a group named in ``todo`` (the names to write; the others,
    finished by an earlier run, are neither read nor computed)."""
    out = []
    for job in jobs:
        if job.name not in todo:
            continue
        item = Loaded(job)
        t0 = time.perf_counter()
        try:
            item.identity = input_identity(job.inputs)
            item.sets = read_frame_sets(
                job.depth,
                job.amplitude,
                height=config.height,
                width=config.width,
                depth_scale=config.depth_scale,
            )
            item.tensors = [frame_set_tensors(fs, allow_empty=True) for fs in item.sets]
        except Exception as exc:  # noqa: BLE001 -- bad input: recorded, the run goes on
            item.error, item.sets, item.tensors = reason(exc), None, None
        item.seconds["read"] = time.perf_counter() - t0
        out.append(item)
    return out


def read_jobs(jobs: list[Job], config: CleanConfig, limit: int | None = None):
    """``(depth, amplitude, camera)``: the readable frames of ``jobs`` in order, of the first
    readable frame's size, at most ``limit``: (N, 1, H, W) metres and camera units (frames with no
    valid pixel left out), and the first camera a file names (None if none does). What the
    data-driven stages and ``tof-fpn calibrate`` measure; frames one pixel wide or high
    (:func:`~.measure.too_thin`) are left out too. :class:`NoFramesError` (a ``ValueError``)
    when there is none, with every file's reason."""
    depth, amplitude, camera = [], [], None
    failures: list[tuple[str, str]] = []
    for job in jobs:
        if job.error is not None:
            failures.append((job.name, job.error))
            continue
        (item,) = load_group([job], {job.name}, config)
        if item.error is not None:
            failures.append((job.name, item.error))
            continue
        found = 0
        for fs, (d, a) in zip(item.sets or [], item.tensors or [], strict=True):
            camera = camera or fs.camera
            if too_thin(d.shape) or (depth and d.shape[-2:] != depth[0].shape[-2:]):
                continue
            has = valid_mask(d, a).flatten(1).any(1)
            depth.append(d[has])
            amplitude.append(a[has])
            found += int(has.sum())
        if not found:
            failures.append((job.name, _unusable(item)))
        if limit is not None and sum(x.shape[0] for x in depth) >= limit:
            break
    if not depth or sum(x.shape[0] for x in depth) == 0:
        raise NoFramesError(failures)
    depth, amplitude = torch.cat(depth)[:limit], torch.cat(amplitude)[:limit]
    return depth, amplitude, camera


def _unusable(item: Loaded) -> str:
    """Why a file that was read gave no frame to measure on."""
    shapes = [tuple(d.shape[-2:]) for d, _ in item.tensors or []]
    if shapes and all(too_thin(s) for s in shapes):
        return f"{'x'.join(map(str, shapes[0]))} frames, one pixel wide: nothing to measure on"
    if not shapes or all(d.shape[0] == 0 for d, _ in item.tensors or []):
        return "no frame"
    return "no frame with a valid pixel"


def _frame_records(records: dict) -> dict:
    """One frame's records: {step: {field: float}} of the (1,) fields."""
    return {
        step: {k: float(v[0]) for k, v in rec.items() if v.dim() == 1}
        for step, rec in records.items()
    }


def compute_group(
    pipeline: torch.nn.Module, group: list[Loaded], device: torch.device | str = "cpu"
) -> list[Loaded]:
    """Run ``pipeline`` on each frame of the group's readable jobs alone (module docstring), then
    its sequence stages per frame set; fills ``cleaned`` (CPU tensors), the records, the kept maps
    and the compute time."""
    device = torch.device(device)
    keep = [(step, f) for step, fields in pipeline.keep_maps.items() for f in fields]
    for item in group:
        if item.error is not None:
            continue
        t0 = time.perf_counter()
        try:
            item.cleaned, item.records = [], []
            item.maps = {f"{st}_{k}": [] for st, k in keep} if keep else None
            for depth, amplitude in item.tensors:
                y, records, maps = _frames(pipeline, item, depth, amplitude, keep, device)
                item.cleaned.append(y)
                item.records.append(records)
                for name in item.maps or {}:
                    item.maps[name].append(maps[name])
        except Exception as exc:  # noqa: BLE001 -- recorded for the file
            item.error = f"compute failed: {reason(exc)}"
        item.seconds["compute"] += time.perf_counter() - t0
        if item.error is None:
            _sequence(pipeline, item)
        if item.error is not None:
            item.cleaned = item.maps = None
        item.tensors = None  # not needed any more (and not to be pickled back)
    return group


def _frames(
    pipeline: torch.nn.Module,
    item: Loaded,
    depth: torch.Tensor,
    amplitude: torch.Tensor,
    keep: list[tuple[str, str]],
    device: torch.device,
) -> tuple[torch.Tensor, list[dict], dict[str, torch.Tensor]]:
    """The frame stages on the (T, 1, H, W) frames of one frame set, one frame per call:
    ``(cleaned, per-frame records, kept maps)``, on the CPU. Frames no stage can work on (no
    valid pixel, one pixel wide) pass as they are, with zero maps and no record; counted in
    ``item``."""
    thin = too_thin(depth.shape)
    has = valid_mask(depth, amplitude).flatten(1).any(1).tolist()
    out, records = [], []
    maps: dict[str, list[torch.Tensor]] = {f"{st}_{k}": [] for st, k in keep}
    for f in range(depth.shape[0]):
        if thin or not has[f]:
            out.append(depth[f : f + 1])
            records.append({})
            for name in maps:
                maps[name].append(torch.zeros_like(depth[f : f + 1]))
            if thin:
                item.thin += 1
            else:
                item.empty += 1
            continue
        # a copy of its own: the frame's memory never depends on the file or process it came from
        d = depth[f : f + 1].to(device, copy=True)
        a = amplitude[f : f + 1].to(device, copy=True)
        y, rec = pipeline(d, a)
        out.append(y.cpu())
        records.append(_frame_records(rec))
        for st, k in keep:
            maps[f"{st}_{k}"].append(rec[st][k].cpu())
    if not out:  # a frame set without frames
        return depth, records, {name: torch.zeros_like(depth) for name in maps}
    return torch.cat(out), records, {name: torch.cat(m) for name, m in maps.items()}


def _sequence(pipeline: torch.nn.Module, item: Loaded) -> None:
    """The pipeline's sequence stages (temporal) over each frame set of ``item`` in order."""
    if len(pipeline.sequence) == 0:
        return
    item.sequence = {name: [] for name in pipeline.sequence}
    t0 = time.perf_counter()
    try:
        for s, (fs, (_, amplitude)) in enumerate(zip(item.sets, item.tensors, strict=True)):
            if too_thin(amplitude.shape):  # copied as it is (module docstring)
                continue
            item.cleaned[s], recs = pipeline.run_sequence(
                item.cleaned[s], amplitude, fs.timestamps_s
            )
            for name, rec in recs.items():
                item.sequence[name].append(rec)
    except Exception as exc:  # noqa: BLE001 -- recorded for the file
        item.error = f"{', '.join(pipeline.sequence)} failed: {reason(exc)}"
    item.seconds["compute"] += time.perf_counter() - t0


def _write_job(item: Loaded, token: str, config: CleanConfig) -> dict:
    job = item.job
    temps: list[tuple[str, str]] = []
    try:
        encoded, clamped = {}, 0
        for fs, y in zip(item.sets, item.cleaned, strict=True):
            encoded[fs.key], n = encode_depth(fs, y, config.rounding, config.output_scale)
            clamped += n
        for dst in job.outputs:
            os.makedirs(os.path.dirname(dst) or ".", exist_ok=True)
        tmp = temporary(job.out_depth, token)
        temps.append((tmp, job.out_depth))
        write_like(job.depth, tmp, encoded, item.sets, config.output_scale)
        for dst, frames in map_files(job, item.maps):
            tmp = temporary(dst, token)
            temps.append((tmp, dst))
            with open(tmp, "wb") as fh:
                np.save(fh, frames[:, 0].numpy().astype(np.float32))
        if job.amplitude is not None:  # the amplitude is not changed: copied byte for byte
            tmp = temporary(job.out_amplitude, token)
            temps.append((tmp, job.out_amplitude))
            shutil.copyfile(job.amplitude, tmp)
        if input_identity(job.inputs) != item.identity:
            raise ValueError("the input changed while it was being cleaned; run again")
        for tmp, dst in temps:
            os.replace(tmp, dst)
    except Exception as exc:  # noqa: BLE001 -- recorded; nothing left under the output names
        for tmp, _ in temps:
            try:
                os.remove(tmp)
            except FileNotFoundError:
                pass
        return {"error": f"write failed: {reason(exc)}"}
    try:
        report = file_report(item.sets, encoded, config.output_scale)
        for step in steps():
            if step.scope == "frame" and step.file_record is not None:
                frames = [
                    r[step.name] for per_set in item.records for r in per_set if step.name in r
                ]
                report[step.report_key] = step.file_record(frames) if frames else None
    except Exception as exc:  # noqa: BLE001 -- the file is written; the record says why not
        report = {"error": f"not measured: {reason(exc)}"}
    return {"clamped": clamped, "report": report}


def map_files(
    job: Job, maps: dict[str, list[torch.Tensor]] | None
) -> list[tuple[str, torch.Tensor]]:
    """``(path, (frames, 1, H, W) map)`` per kept map and frame set (e.g. ``--flying-confidence``):
    ``<output stem>.<step>_<field>.npy`` beside the depth output (``.<set>`` before ``.npy``
    when the file has several frame sets); none without kept maps."""
    out = []
    for name, per_set in (maps or {}).items():
        stem = os.path.splitext(job.out_depth)[0] + "." + name
        if len(per_set) == 1:
            out.append((stem + ".npy", per_set[0]))
        else:
            out += [(f"{stem}.{s}.npy", m) for s, m in enumerate(per_set)]
    return out


def write_group(group: list[Loaded], token: str, root: str, config: CleanConfig) -> list[dict]:
    """Encode and write the group's jobs to write (temporary name, then ``os.replace``); returns
    their manifest records (``root``: OUTPUT, to which the recorded output paths are relative)."""
    records = []
    for item in group:
        job = item.job
        rec = {"file": job.name, "time": None}
        if item.error is None:
            t0 = time.perf_counter()
            res = _write_job(item, token, config)
            item.seconds["write"] = time.perf_counter() - t0
            item.error = res.get("error")
            rec["clamped"] = res.get("clamped", 0)
            if "report" in res:
                rec["report"] = res["report"]
            if item.empty:
                rec["empty_frames"] = item.empty  # no valid pixel: written as they came
            if item.thin:  # one pixel wide: written as they came
                total = sum(int(fs.depth.shape[0]) for fs in item.sets)
                rec["note"] = (
                    THIN_NOTE
                    if item.thin == total
                    else f"{item.thin} of {total} frames one pixel wide: copied"
                )
            for step in steps():  # a sequence step's record per frame set (temporal)
                if step.record_key == "file" and item.sequence and step.name in item.sequence:
                    rec[step.report_key] = step.file_record(item.sequence[step.name])
        if item.error is None:
            rec.update(
                status="done",
                outputs=[os.path.relpath(p, root).replace(os.sep, "/") for p in job.outputs],
                frames=sum(int(fs.depth.shape[0]) for fs in item.sets),
                input=item.identity,
            )
            for name in item.maps or {}:  # kept maps (--flying-confidence)
                rec[name] = [
                    os.path.relpath(p, root).replace(os.sep, "/")
                    for p, _ in map_files(job, {name: item.maps[name]})
                ]
        else:
            rec.update(status="failed", error=item.error)
        rec.update({f"{k}_s": round(v, 6) for k, v in item.seconds.items()})
        rec["time"] = now()
        records.append(finite_values(rec))  # JSON: null where a measure is undefined, no NaN
        item.sets = item.cleaned = item.maps = None
    return records
