"""The manifest of a ``tof-fpn clean`` run: ``OUTPUT/manifest.jsonl``, one JSON object per line.

Lines are appended, never rewritten, each with one ``os.write`` on a file opened ``O_APPEND`` (a
killed process leaves whole lines; a torn last line, which only a crash of the machine could
leave, is skipped when read and closed with a newline before the next append). Kinds of lines:

* ``{"event": "start", "run", "version", "engine", "jobs", "todo", "already_done", "pipeline",
  "cameras", "time"}``: a run starts. ``cameras``: one ``{"key", "files", "pipeline"}`` per
  camera group (:mod:`.cameras`; ``files``: how many, ``pipeline``: its stages as measured,
  :func:`~.pipeline.describe`; ``note``: why nothing was measured, when so); ``pipeline``: the
  one group's, ``null`` when the run has several;
* ``{"file", "status", ...}``: one per file and run, ``camera`` the key of its camera group (a file
  that failed when planned has none). ``status`` is ``"done"`` (``outputs``,
  ``frames``, ``read_s``, ``compute_s``, ``write_s`` in seconds, ``clamped``: valid pixels whose
  cleaned depth did not fit the stored dtype, ``input``: the inputs' sizes and modification times)
  or ``"failed"`` (``error``: the reason). A file is recorded done only after its outputs were
  renamed into place;
* ``{"event": "end", "run", "done", "failed", "interrupted", "seconds", "time"}``.

A file counts as finished (skipped by a resumed run) when its last record is ``done``, its inputs
have the recorded sizes and modification times and its outputs exist.
"""

from __future__ import annotations

import json
import os
import time

__all__ = ["Manifest", "finished", "input_identity", "read_manifest"]


def now() -> str:
    """UTC time of day, ISO 8601 with milliseconds."""
    t = time.time()
    return time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(t)) + f".{int(t % 1 * 1000):03d}Z"


def input_identity(paths) -> dict:
    """``{"size": [...], "mtime_ns": [...]}`` of the input files (what a resumed run compares)."""
    stats = [os.stat(p) for p in paths]
    return {"size": [s.st_size for s in stats], "mtime_ns": [s.st_mtime_ns for s in stats]}


class Manifest:
    """Appends records to ``path`` (created if missing), one ``os.write`` per line."""

    def __init__(self, path: str) -> None:
        self.path = path
        self._fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        size = os.fstat(self._fd).st_size
        if size:
            with open(path, "rb") as fh:
                fh.seek(size - 1)
                if fh.read(1) != b"\n":  # a torn last line: end it, so it stays one bad line
                    os.write(self._fd, b"\n")

    def write(self, record: dict) -> None:
        os.write(self._fd, (json.dumps(record, sort_keys=True) + "\n").encode())

    def close(self) -> None:
        if self._fd >= 0:
            os.fsync(self._fd)
            os.close(self._fd)
            self._fd = -1

    def __enter__(self) -> Manifest:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def read_manifest(path: str) -> list[dict]:
    """The records of a manifest (none if it does not exist); lines that are not JSON objects
    (a torn line) are skipped."""
    if not os.path.isfile(path):
        return []
    out = []
    with open(path, encoding="utf-8", errors="replace") as fh:
        for line in fh:
            try:
                rec = json.loads(line)
            except json.JSONDecodeError:
                continue
            if isinstance(rec, dict):
                out.append(rec)
    return out


def finished(records: list[dict], jobs) -> set[str]:
    """Names of the jobs whose last record is ``done`` with unchanged inputs and outputs present."""
    last: dict[str, dict] = {}
    for rec in records:
        if "file" in rec:
            last[rec["file"]] = rec
    done = set()
    for job in jobs:
        rec = last.get(job.name)
        if rec is None or rec.get("status") != "done" or job.error is not None:
            continue
        try:
            same = rec.get("input") == input_identity(job.inputs)
        except OSError:
            continue
        if same and all(os.path.isfile(p) for p in job.outputs):
            done.add(job.name)
    return done
