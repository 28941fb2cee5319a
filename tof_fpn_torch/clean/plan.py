"""What a ``tof-fpn clean`` run reads and writes: the jobs (one per frame file), the safety checks
on INPUT / OUTPUT, temporary names and atomic renames.

INPUT is a frame file or a directory tree; OUTPUT is always a directory. A job is one frame file
of :func:`tof_fpn_torch.io.find_frames`' naming rule (``<name>.npz`` / ``.h5`` / ``.hdf5`` holding
depth and amplitude, or ``<name>_depth.<ext>`` + ``<name>_amplitude.<ext>``), written under
OUTPUT at the same relative path and name. Files of other suffixes are ignored; a ``_depth`` file
without its ``_amplitude`` (or the reverse) and a directory that cannot be listed become failed
jobs (``Job.error``), so the manifest lists them and the run goes on.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from ..io.pairs import PAIR_SUFFIXES, SINGLE_SUFFIXES

__all__ = [
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
        out_depth, out_amplitude: output paths, the same names under OUTPUT.
        error: why the job cannot run (found when planning), else None.
    """

    name: str
    depth: str
    amplitude: str | None
    out_depth: str
    out_amplitude: str | None
    error: str | None = None

    @property
    def inputs(self) -> tuple[str, ...]:
        return (self.depth,) if self.amplitude is None else (self.depth, self.amplitude)

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
    if os.path.isdir(output) and any(os.scandir(output)):
        ours = (os.path.isfile(os.path.join(output, n)) for n in (MANIFEST, SAVED_CONFIG))
        if not any(ours):  # clean.toml alone: a run stopped before its manifest was opened
            raise ValueError(
                f"OUTPUT {output!r} is not empty and holds no {MANIFEST} (not a tof-fpn clean "
                "output); choose a new or empty directory"
            )


def _frames_in(folder: Path, names: list[str], rel: str, out: Path) -> list[Job]:
    jobs, singles = [], {}
    for fname in sorted(names):
        p = folder / fname
        suffix = p.suffix.lower()
        key = f"{rel}{fname}"
        if suffix in PAIR_SUFFIXES:
            jobs.append(Job(key, str(p), None, str(out / key), None))
        elif suffix in SINGLE_SUFFIXES:
            stem = p.name[: -len(p.suffix)]
            ending = next((e for e in _ENDINGS if stem.endswith(e)), None)
            if ending is not None:
                singles.setdefault((stem[: -len(ending)], suffix), {})[_ENDINGS[ending]] = fname
    for (stem, suffix), pair in sorted(singles.items()):
        d, a = pair.get("depth"), pair.get("amplitude")
        if d is None or a is None:
            have = d or a
            missing = f"{stem}_{'amplitude' if d else 'depth'}{suffix}"
            jobs.append(
                Job(
                    f"{rel}{have}",
                    str(folder / have),
                    None,
                    str(out / rel / have),
                    None,
                    f"no partner: {missing} is missing (pairs are <name>_depth.<ext> + "
                    "<name>_amplitude.<ext>)",
                )
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


def plan_jobs(input_path: str, output: str) -> list[Job]:
    """Every job of INPUT (a frame file or a directory tree, walked without following links),
    sorted by name; unreadable directories and unmatched files are jobs with an ``error``."""
    src, out = Path(input_path), Path(output)
    if src.is_file():
        names = [src.name]
        stem = src.name[: -len(src.suffix)] if src.suffix else src.name
        for ending, other in (("_depth", "_amplitude"), ("_amplitude", "_depth")):
            partner = stem[: -len(ending)] + other + src.suffix
            if stem.endswith(ending) and (src.parent / partner).is_file():
                names.append(partner)
        jobs = _frames_in(src.parent, names, "", out)
        if not jobs:
            raise ValueError(
                f"INPUT {input_path!r} is not a frame file (suffixes {list(PAIR_SUFFIXES)}, or "
                f"<name>_depth.<ext> / <name>_amplitude.<ext> with <ext> in {list(SINGLE_SUFFIXES)})"
            )
        return jobs
    jobs: list[Job] = []
    errors: list[Job] = []

    def onerror(exc: OSError) -> None:
        rel = Path(exc.filename).relative_to(src).as_posix() + "/"
        errors.append(Job(rel, exc.filename, None, "", None, f"cannot read directory: {exc}"))

    for folder, dirs, files in os.walk(src, onerror=onerror):
        dirs.sort()
        rel = Path(folder).relative_to(src).as_posix()
        rel = "" if rel == "." else rel + "/"
        jobs += _frames_in(Path(folder), files, rel, out)
    return sorted(jobs + errors, key=lambda j: j.name)


def groups_of(jobs: list[Job], batch: int) -> list[list[Job]]:
    """The runnable jobs in fixed groups of ``batch`` (by position in the sorted list), so that a
    resumed run and the Ray engine form the same groups, and so the same compute batches."""
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
