"""``tof-fpn convert INPUT OUTPUT``: camera files to the package's recording format or PNG pairs.

INPUT is what ``tof-fpn clean`` takes (a frame or camera file, a ROS 2 bag folder or a directory
tree; the file names of :mod:`tof_fpn_torch.io.camera_files`). Each input becomes, under OUTPUT at
its relative folder, ``<stem>.npz`` (a version-1 recording, :func:`tof_fpn_torch.io.write_recording`:
depth in metres, the amplitude as stored, timestamps and the reader's meta with ``camera``) or,
with ``--to png``, ``<stem>_depth.png`` (uint16 mm, 0 invalid) + ``<stem>_amplitude.png`` (uint16,
rounded), ``<stem>_<frame>_depth.png`` ... when it has several frames. ``<stem>``: the file name
without its suffix, ``_depth`` ending or ADI pattern (``wall_depth_u16le_512x512.bin`` -> ``wall``).

Nothing is overwritten: outputs are written to temporary names and renamed, an output that exists
already makes that input fail. Exit status: 0; 1 when some inputs failed (one line each on stderr,
the others are written); 2 for a bad argument or an INPUT with nothing to convert.
"""

from __future__ import annotations

import argparse
import os
import secrets
import sys
from pathlib import Path

from ..clean.plan import plan_jobs
from ..io import read_any_recording, write_png, write_recording
from ..io.camera_files import recording_stem
from ._common import UsageError, float_arg, int_arg

#: ``--to`` values
TARGETS = ("npz", "png")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "convert",
        help="camera files (.mkv, .bag, ROS 2 bags, ADI raw, ...) to recordings or PNG pairs",
        description="Read every camera file of INPUT (an Azure Kinect .mkv, a ROS 1 / RealSense "
        ".bag, a ROS 2 bag, ADI vendor raw files, and the frame files tof-fpn clean takes) and "
        "write it under OUTPUT at the same relative folder as <stem>.npz (the recording format: "
        "metres, amplitude as stored, timestamps, camera meta) or, with --to png, as "
        "<stem>_depth.png (uint16 mm) + <stem>_amplitude.png. Never overwrites a file.",
    )
    p.add_argument("input", metavar="INPUT", help="a camera / frame file or a directory")
    p.add_argument("output", metavar="OUTPUT", help="output directory (made if missing)")
    p.add_argument("--to", choices=TARGETS, default="npz", help="output format (default npz)")
    p.add_argument("--depth-topic", metavar="TOPIC", help="bags: the depth Image topic")
    p.add_argument("--amplitude-topic", metavar="TOPIC", help="bags: the IR / amplitude topic")
    p.add_argument("--depth-scale", type=float_arg(0.0, open_lo=True), help="metres per unit")
    p.add_argument("--height", type=int_arg(1), help="rows of raw .bin / .raw frames")
    p.add_argument("--width", type=int_arg(1), help="columns of raw .bin / .raw frames")
    p.add_argument("--compress", action="store_true", help="deflate the .npz arrays")
    p.set_defaults(func=run)


def _check_paths(src: str, output: str) -> None:
    if not os.path.exists(src):
        raise UsageError(f"INPUT {src!r} does not exist")
    if os.path.lexists(output) and not os.path.isdir(output):
        raise UsageError(f"OUTPUT {output!r} is a file; it must be a directory (made if missing)")
    s, o = Path(src).resolve(), Path(output).resolve()
    if os.path.isdir(src) and (o == s or s in o.parents):
        raise UsageError(f"OUTPUT {output!r} is inside INPUT {src!r}; choose a directory outside")
    if os.path.isfile(src) and o == s.parent:
        raise UsageError(
            f"OUTPUT {output!r} is the directory of INPUT {src!r}; choose another directory"
        )


def _names(rec, base: str, to: str) -> list[tuple[str, str, int | None]]:
    """``(path, kind, frame)`` of every output of one input (``kind`` None: the recording)."""
    if to == "npz":
        return [(f"{base}.npz", "recording", None)]
    t = rec.frames
    tags = [""] if t == 1 else [f"_{i:0{len(str(t - 1))}d}" for i in range(t)]
    return [
        (f"{base}{tag}_{kind}.png", kind, i)
        for i, tag in enumerate(tags)
        for kind in ("depth", "amplitude")
    ]


def _free(names, seen: dict[str, str]) -> None:
    """Refuse an output name that exists or that another input of this run wrote."""
    for path, _, _ in names:
        if path in seen:
            raise ValueError(f"its output {path} is also the output of {seen[path]}")
        if os.path.lexists(path):
            raise ValueError(f"{path} exists; convert does not overwrite files")


def _write(rec, names, compress: bool) -> None:
    """Write every output to a temporary name, then rename them all (nothing left on failure)."""
    token = f"{os.getpid()}-{secrets.token_hex(4)}"
    temps = []
    try:
        for path, kind, i in names:
            os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
            tmp = os.path.join(os.path.dirname(path), f".{os.path.basename(path)}.{token}.tmp")
            temps.append((tmp, path))
            if kind == "recording":
                write_recording(tmp, rec, compress=compress)
            else:
                frame = (rec.depth if kind == "depth" else rec.amplitude)[i : i + 1]
                write_png(tmp, frame, kind)
        for tmp, path in temps:
            os.replace(tmp, path)
    finally:
        for tmp, _ in temps:
            if os.path.exists(tmp):
                os.remove(tmp)


def run(args: argparse.Namespace) -> int:
    if (args.height is None) != (args.width is None):
        raise UsageError("--height and --width go together (raw .bin / .raw frames)")
    _check_paths(args.input, args.output)
    jobs = plan_jobs(args.input, args.output)  # ValueError (exit 2): nothing to convert
    if not os.path.isdir(args.output):
        os.makedirs(args.output)
        print(f"created directory {args.output}")
    failures = [(job.name, job.error) for job in jobs if job.error is not None]
    done, frames, seen = 0, 0, {}
    for job in (j for j in jobs if j.error is None):
        rel = os.path.dirname(job.name.rstrip("/"))
        base = os.path.join(args.output, rel, recording_stem(job.name))
        try:
            if args.to == "npz":  # the name is known: refuse before reading
                _free([(f"{base}.npz", None, None)], seen)
            rec = read_any_recording(
                job.depth,
                job.amplitude,
                height=args.height,
                width=args.width,
                depth_scale=args.depth_scale,
                depth_topic=args.depth_topic,
                amplitude_topic=args.amplitude_topic,
            )
            names = _names(rec, base, args.to)
            _free(names, seen)
            seen.update({p: job.name for p, _, _ in names})
            _write(rec, names, args.compress)
        except (ValueError, ImportError, OSError) as exc:
            failures.append((job.name, " ".join(str(exc).split())))
            continue
        done += 1
        frames += rec.frames
        camera = rec.meta.get("camera") or "unknown"
        print(f"{job.name} -> {names[0][0]}{' ...' if len(names) > 1 else ''} "
              f"({rec.frames} frame(s), camera {camera})")  # fmt: skip
    print(f"converted {done} file(s) ({frames} frames) to {args.output}; {len(failures)} failed")
    for name, reason in failures:
        print(f"tof-fpn convert: error: {name}: {reason}", file=sys.stderr)
    return 1 if failures else 0
