"""What a ``tof-fpn clean`` run reads and writes: the jobs (one per frame file), the safety checks
on INPUT / OUTPUT, temporary names and atomic renames.

INPUT is a frame file, a ROS 2 bag folder or a directory tree; OUTPUT is always a directory. A job
is one frame file: ``<name>.npz`` / ``.h5`` / ``.hdf5`` holding depth and amplitude,
``<name>_depth.<ext>`` + ``<name>_amplitude.<ext>``, or a camera file of
:mod:`tof_fpn_torch.io.camera_files` (an Azure Kinect ``.mkv``, a ROS 1 ``.bag``, a ROS 2 bag
folder / ``.mcap`` / ``.db3``, ADI vendor-named raw files), written under OUTPUT at the same
relative path and name -- a recording container as ``<stem>.npz`` beside it. Files of other
suffixes are ignored; a pair's file without its partner, a directory that cannot be listed and
two inputs with one output name become failed jobs (``Job.error``), so the manifest lists them
and the run goes on. A folder with nothing to clean is a ``ValueError``.
"""

from __future__ import annotations

import dataclasses
import os
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

from ..io.camera_files import (
    ACCEPTED,
    CONTAINER_SUFFIXES,
    is_camera_recording,
    is_ros2_bag_dir,
    recording_stem,
    ros2_bag_files,
    vendor_name,
    vendor_partner,
)
from ..io.pairs import PAIR_SUFFIXES, SINGLE_SUFFIXES

__all__ = [
    "LOCK",
    "MANIFEST",
    "SAVED_CONFIG",
    "TMP_MARK",
    "Job",
    "check_paths",
    "groups_of",
    "plan_jobs",
    "remove_stale_temporaries",
    "temporary",
]

#: the manifest and the saved configuration, inside OUTPUT
MANIFEST = "manifest.jsonl"
SAVED_CONFIG = "clean.toml"
#: held (``flock``) by the run writing OUTPUT, so that two runs never write one OUTPUT at once
LOCK = ".tof-fpn-clean.lock"
#: every temporary file is ``.<name>.tofclean-<token>.tmp`` in its destination directory
TMP_MARK = ".tofclean-"
_ENDINGS = {"_depth": "depth", "_amplitude": "amplitude"}


@dataclass(frozen=True)
class Job:
    """One frame file: where it is read and where its output goes.

    Attributes:
        name: the depth file's path relative to INPUT's directory, ``/``-separated (the manifest
            key; for a directory that cannot be read, its relative path with a trailing ``/``).
        depth, amplitude: input paths (``amplitude`` None for ``.npz`` / ``.h5``).
        out_depth, out_amplitude: output paths, the same names under OUTPUT (a recording
            container's: ``<stem>.npz``).
        error: why the job cannot run (found when planning), else None.
        members: the files of a ROS 2 bag folder (``depth`` is the folder), else empty; they
            are inputs too (sizes and times recorded, checked on resume).
    """

    name: str
    depth: str
    amplitude: str | None
    out_depth: str
    out_amplitude: str | None
    error: str | None = None
    members: tuple[str, ...] = ()

    @property
    def inputs(self) -> tuple[str, ...]:
        pair = (self.depth,) if self.amplitude is None else (self.depth, self.amplitude)
        return pair + self.members

    @property
    def outputs(self) -> tuple[str, ...]:
        return (
            (self.out_depth,)
            if self.out_amplitude is None
            else (self.out_depth, self.out_amplitude)
        )


def _inside(child: Path, parent: Path) -> bool:
    return child == parent or parent in child.parents


def check_paths(input_path: str, output: str) -> None:
    """Refuse (``ValueError``, one line) an INPUT that does not exist and an OUTPUT that would
    overwrite INPUT: OUTPUT equal to INPUT, inside INPUT, a file, or the directory INPUT (a file)
    lies in; and an OUTPUT that exists, is not empty and was not made by ``tof-fpn clean`` (no
    manifest): its files are someone else's."""
    src = Path(input_path)
    if not src.exists():
        raise ValueError(f"INPUT {input_path!r} does not exist")
    if not (src.is_dir() or src.is_file()):
        raise ValueError(f"INPUT {input_path!r} is neither a file nor a directory")
    s, o = src.resolve(), Path(output).resolve()
    if src.is_dir() and _inside(o, s):
        raise ValueError(
            f"OUTPUT {output!r} is {'INPUT itself' if o == s else 'inside INPUT'} {input_path!r}: "
            "it would overwrite or mix with the input; choose a directory outside INPUT"
        )
    if src.is_file() and (o == s or o == s.parent):
        raise ValueError(
            f"OUTPUT {output!r} is {'INPUT itself' if o == s else 'the directory of INPUT'} "
            f"{input_path!r}: the output file would overwrite the input; choose another directory"
        )
    if os.path.lexists(output) and not os.path.isdir(output):
        raise ValueError(f"OUTPUT {output!r} is a file; it must be a directory (made if missing)")
    if os.path.isdir(output) and any(e.name != LOCK for e in os.scandir(output)):
        ours = (os.path.isfile(os.path.join(output, n)) for n in (MANIFEST, SAVED_CONFIG))
        if not any(ours):  # clean.toml alone: a run stopped before its manifest was opened
            raise ValueError(
                f"OUTPUT {output!r} is not empty and holds no {MANIFEST} (not a tof-fpn clean "
                "output); choose a new or empty directory"
            )


def _partner(fname: str) -> tuple[str, str] | None:
    """``(kind, partner file name)`` of one file of a pair (``<name>_depth`` / ``_amplitude``, or an
    ADI vendor pair), else None."""
    other = vendor_partner(fname)
    if other is not None:
        return ("depth" if vendor_name(fname).kind == "depth" else "amplitude"), other
    stem, suffix = os.path.splitext(fname)
    if suffix.lower() not in SINGLE_SUFFIXES:
        return None
    for ending, kind in _ENDINGS.items():
        if stem.endswith(ending):
            other = "_amplitude" if kind == "depth" else "_depth"
            return kind, stem[: -len(ending)] + other + suffix
    return None


def _frames_in(folder: Path, names: list[str], rel: str, out: Path) -> list[Job]:
    jobs, pairs = [], {}
    for fname in sorted(names):
        p = folder / fname
        suffix = p.suffix.lower()
        key = f"{rel}{fname}"
        vendor = vendor_name(fname)
        if suffix in CONTAINER_SUFFIXES or (suffix in PAIR_SUFFIXES and is_camera_recording(p)):
            jobs.append(  # a container found by its content too (an ESPROS toolkit .h5)
                Job(key, str(p), None, str(out / rel / f"{recording_stem(fname)}.npz"), None)
            )
        elif suffix in PAIR_SUFFIXES or (vendor is not None and vendor.kind == "interleaved"):
            jobs.append(Job(key, str(p), None, str(out / key), None))
        elif (pair := _partner(fname)) is not None:
            kind, other = pair
            names_ = (fname, other) if kind == "depth" else (other, fname)
            key_ = tuple(os.path.splitext(n)[0] + os.path.splitext(n)[1].lower() for n in names_)
            pairs.setdefault(key_, {})[kind] = fname
    for (d_name, a_name), pair in sorted(pairs.items()):
        d, a = pair.get("depth"), pair.get("amplitude")
        if d is None or a is None:
            have = d or a
            rule = (
                "ADI pairs are <name>_depth_u16le_<H>x<W>.bin + <name>_ir_u16le_<H>x<W>.bin"
                if vendor_name(have)
                else "pairs are <name>_depth.<ext> + <name>_amplitude.<ext>"
            )
            missing = a_name if d else d_name
            error = f"no partner: {missing} is missing ({rule})"
            jobs.append(
                Job(f"{rel}{have}", str(folder / have), None, str(out / rel / have), None, error)
            )
            continue
        jobs.append(
            Job(
                f"{rel}{d}",
                str(folder / d),
                str(folder / a),
                str(out / rel / d),
                str(out / rel / a),
            )
        )
    return jobs


def _ros2_job(path: Path, rel: str, out: Path) -> Job:
    key = f"{rel}{path.name}"
    try:
        members = ros2_bag_files(path)
    except OSError as exc:
        return Job(key, str(path), None, "", None, f"cannot read directory: {exc}")
    return Job(key, str(path), None, str(out / rel / f"{path.name}.npz"), None, members=members)


def _nothing_found(input_path: str, suffixes: Counter, folders: int) -> ValueError:
    """The one-line error for a folder where nothing is a frame file."""
    if not suffixes:
        found = "it is empty" if not folders else f"it holds {folders} folder(s) and no file"
    else:
        counts = ", ".join(f"{n} {s or '(no suffix)'}" for s, n in sorted(suffixes.items()))
        found = f"it holds {sum(suffixes.values())} file(s) ({counts})"
    return ValueError(f"INPUT {input_path!r} holds no frame file: {found}; accepted: {ACCEPTED}")


def _collisions(jobs: list[Job]) -> list[Job]:
    """A recording's output ``<stem>.npz`` must not be another job's output too: a job whose
    output keeps its input's name (``take.npz``) keeps it, the renamed ones (``take.bag``) fail."""
    owners: dict[str, list[Job]] = {}
    for job in jobs:
        if job.error is None:
            owners.setdefault(job.out_depth, []).append(job)
    out = []
    for job in jobs:
        group = owners.get(job.out_depth, [])
        renamed = os.path.basename(job.out_depth) != os.path.basename(job.depth)
        if job.error is None and len(group) > 1 and renamed:
            others = [j.name for j in group if j is not job]
            job = dataclasses.replace(
                job,
                error=f"its output {os.path.basename(job.out_depth)} is also the output of "
                f"{others}; rename one of them",
            )
        out.append(job)
    return out


def plan_jobs(input_path: str, output: str) -> list[Job]:
    """Every job of INPUT (a frame file, a ROS 2 bag folder or a directory tree, walked without
    following links), sorted by name; unreadable directories, unmatched files and outputs that
    two inputs would share are jobs with an ``error``. ``ValueError`` when INPUT holds nothing to
    clean (an empty folder too), naming what it holds and what is accepted."""
    src, out = Path(input_path), Path(output)
    if src.is_dir() and is_ros2_bag_dir(src):
        return [_ros2_job(src, "", out)]
    if src.is_file():
        names = [src.name]
        pair = _partner(src.name)
        if pair is not None and (src.parent / pair[1]).is_file():
            names.append(pair[1])
        jobs = _frames_in(src.parent, names, "", out)
        if not jobs:
            raise ValueError(f"INPUT {input_path!r} is not a frame file; accepted: {ACCEPTED}")
        return jobs
    jobs: list[Job] = []
    errors: list[Job] = []
    suffixes: Counter = Counter()
    folders = 0

    def onerror(exc: OSError) -> None:
        rel = Path(exc.filename).relative_to(src).as_posix() + "/"
        errors.append(Job(rel, exc.filename, None, "", None, f"cannot read directory: {exc}"))

    for folder, dirs, files in os.walk(src, onerror=onerror):
        dirs.sort()
        rel = Path(folder).relative_to(src).as_posix()
        rel = "" if rel == "." else rel + "/"
        bags = [d for d in dirs if not os.path.islink(os.path.join(folder, d))]
        bags = [d for d in bags if is_ros2_bag_dir(os.path.join(folder, d))]
        jobs += [_ros2_job(Path(folder) / d, rel, out) for d in bags]
        dirs[:] = [d for d in dirs if d not in bags]
        folders += len(dirs)
        suffixes.update(Path(f).suffix.lower() for f in files)
        jobs += _frames_in(Path(folder), files, rel, out)
    if not jobs and not errors:
        raise _nothing_found(input_path, suffixes, folders)
    return sorted(_collisions(jobs) + errors, key=lambda j: j.name)


def groups_of(jobs: list[Job], batch: int) -> list[list[Job]]:
    """The runnable jobs in groups of ``batch`` (by position in the sorted list): the unit of work
    of a worker or a Ray task. The bytes written do not depend on the groups (every frame is
    computed alone, :mod:`.work`)."""
    runnable = [j for j in jobs if j.error is None]
    return [runnable[i : i + batch] for i in range(0, len(runnable), batch)]


def temporary(dst: str, token: str) -> str:
    """A temporary name for ``dst`` in its own directory (so the rename is atomic)."""
    d, n = os.path.split(dst)
    return os.path.join(d, f".{n}{TMP_MARK}{token}.tmp")


def remove_stale_temporaries(output: str) -> int:
    """Delete temporary files a killed run left under OUTPUT; returns how many."""
    n = 0
    for folder, _, files in os.walk(output):
        for f in files:
            if f.startswith(".") and TMP_MARK in f and f.endswith(".tmp"):
                try:
                    os.remove(os.path.join(folder, f))
                    n += 1
                except FileNotFoundError:
                    pass
    return n
