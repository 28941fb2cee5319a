""":func:`clean`: a whole ``tof-fpn clean`` run, engine-independent (safety, resume, manifest).

1. Refuse an OUTPUT that would overwrite INPUT or someone else's files (:func:`~.plan.check_paths`).
2. Plan the jobs (:func:`~.plan.plan_jobs`), group them by camera (:func:`~.cameras.camera_groups`)
   and build one pipeline per camera (measuring data-driven stages on frames spread over that
   camera's files), all before anything is written.
3. Make OUTPUT, save the configuration as ``clean.toml`` (or, resuming, refuse a different one),
   read the manifest: files finished by an earlier run are skipped; temporary files a killed run
   left are removed.
4. Run the engine (local or Ray) over the groups with unfinished files, each through its camera's
   pipeline; append each file's record (naming its camera) to the manifest as its outputs land;
   show a progress bar (files/s, ETA).
5. SIGTERM / SIGINT: stop taking new groups, finish the ones in flight, record them, remove
   temporary files, write the ``end`` record; :attr:`CleanReport.status` is ``128 + signal``.
"""

from __future__ import annotations

import contextlib
import importlib.util
import os
import secrets
import signal
import sys
import threading
import time
from dataclasses import dataclass, field

import torch
from tqdm import tqdm

from .. import __version__
from .cameras import Camera, build_cameras, learned_patterns, stage_lines, start_fields
from .config import CleanConfig, config_to_toml, load_config
from .figure import report_figure
from .manifest import Manifest, finished, now, read_manifest
from .measure import summarise
from .plan import (
    LOCK,
    MANIFEST,
    SAVED_CONFIG,
    TMP_MARK,
    check_paths,
    groups_of,
    plan_jobs,
    remove_stale_temporaries,
)
from .steps import steps

__all__ = ["ENGINES", "CleanReport", "clean", "resolve_device"]

ENGINES = ("local", "ray")
#: failed files listed by :meth:`CleanReport.summary` (all are in the manifest)
SHOWN_FAILURES = 10


@dataclass
class CleanReport:
    """What a run did. ``status``: 0, 1 when some files failed, ``128 + signal`` when stopped."""

    output: str
    jobs: int = 0
    already_done: int = 0
    done: int = 0
    failed: int = 0
    frames: int = 0
    seconds: float = 0.0
    interrupted: int | None = None
    steps: dict = field(default_factory=lambda: {"read": 0.0, "compute": 0.0, "write": 0.0})
    failures: list = field(default_factory=list)
    created: bool = False
    stage: str = ""
    records: list = field(default_factory=list)
    figure: str | None = None
    #: the run has no stage at all (every one switched off)
    stages_off: bool = False

    @property
    def status(self) -> int:
        if self.interrupted is not None:
            return 128 + self.interrupted
        return 1 if self.failed else 0

    def add(self, rec: dict) -> None:
        """Count one file's manifest record."""
        for step in self.steps:
            self.steps[step] += rec.get(f"{step}_s", 0.0)
        if rec["status"] == "done":
            self.done += 1
            self.frames += rec["frames"]
            kept = {s.report_key: rec.get(s.report_key) for s in steps() if s.record_key == "file"}
            self.records.append(
                {"status": "done", "report": rec.get("report"), "note": rec.get("note"), **kept}
            )
        else:
            self.failed += 1
            self.failures.append((rec["file"], rec["error"]))

    def summary(self) -> str:
        """What the command prints: the stage, the counts, what the cleaning did (module
        :mod:`.measure`), one line per failed file (the first :data:`SHOWN_FAILURES`)."""
        rate = self.frames / self.seconds if self.seconds > 0 else 0.0
        lines = [self.stage] if self.stage else []
        lines.append(
            f"cleaned {self.done} file(s) ({self.frames} frames) in {self.seconds:.1f} s, "
            f"{rate:.1f} frames/s; {self.failed} failed; {self.already_done} already done; "
            f"output {self.output}, manifest {os.path.join(self.output, MANIFEST)}"
        )
        lines += summarise(self.records, stages_off=self.stages_off)
        lines += [x for s in steps() if s.scope == "sequence" for x in s.summary(self.records)]
        if self.figure:
            lines.append(f"figure: {self.figure}")
        for name, why in self.failures[:SHOWN_FAILURES]:
            lines.append(f"failed: {name}: {why}")
        if len(self.failures) > SHOWN_FAILURES:
            lines.append(f"... and {len(self.failures) - SHOWN_FAILURES} more failed (manifest)")
        return "\n".join(lines)


def resolve_device(device: str | torch.device = "auto") -> torch.device:
    """``"auto"``: the GPU when there is one, else the CPU; ``"cpu"``, ``"cuda"``, ``"cuda:N"``."""
    if str(device) == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError):
        raise ValueError(f"device must be 'auto', 'cpu' or 'cuda[:N]', got {device!r}") from None
    if dev.type not in ("cpu", "cuda"):
        raise ValueError(f"device must be 'auto', 'cpu' or 'cuda[:N]', got {device!r}")
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"device {device!r}: no CUDA device here; use 'cpu' or 'auto'")
    return dev


@contextlib.contextmanager
def output_lock(output: str):
    """Hold ``OUTPUT/.tof-fpn-clean.lock`` (an exclusive ``flock``, the file holding the pid) for
    the run; ``ValueError`` when another run holds it. The file is removed when the run ends; a
    killed run leaves it, unlocked (the kernel releases the lock with the process), and the next
    run takes it over. (Where ``fcntl`` is missing, e.g. on Windows, nothing is locked.)"""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        yield
        return
    fd = os.open(os.path.join(output, LOCK), os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            owner = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
            raise ValueError(
                f"OUTPUT {output!r} is being written by another tof-fpn clean (pid {owner}); "
                "wait for it to finish, or choose another OUTPUT"
            ) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, str(os.getpid()).encode(), 0)
        try:
            yield
        finally:  # still held: a run starting now opens a new file, after this one is done
            with contextlib.suppress(FileNotFoundError):
                os.remove(os.path.join(output, LOCK))
    finally:
        os.close(fd)


@contextlib.contextmanager
def _signals():
    """Catch SIGTERM / SIGINT into a flag (only in the main thread, where Python can); a second
    signal ends the process at once (atomic writes keep the output consistent)."""
    caught: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield caught
        return
    old = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT)}

    def handler(signum, frame):
        if caught:  # a second signal: stop now, the default way (resume still works)
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)
        caught.append(signum)

    for s in old:
        signal.signal(s, handler)
    try:
        yield caught
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def _saved_config(output: str, config: CleanConfig) -> None:
    """Save ``clean.toml`` (atomically), or refuse one that differs (a resumed run)."""
    path = os.path.join(output, SAVED_CONFIG)
    if os.path.isfile(path):
        if load_config(path).identity() != config.identity():
            raise ValueError(
                f"OUTPUT {output!r} was made with another configuration ({path}); resume with "
                "that one (--config it) or choose a new OUTPUT"
            )
        return
    tmp = os.path.join(output, f".{SAVED_CONFIG}{TMP_MARK}{os.getpid()}.tmp")
    with open(tmp, "w") as fh:
        fh.write(config_to_toml(config))
    os.replace(tmp, path)


def clean(
    input_path: str,
    output: str,
    config: CleanConfig | None = None,
    *,
    workers: int = 0,
    device: str | torch.device = "auto",
    engine: str = "local",
    progress: bool | None = False,
    concurrency: int | None = None,
    ray_address: str | None = None,
    compute_in_workers: bool | None = None,
    figure: bool = True,
) -> CleanReport:
    """Clean every frame file of ``input_path`` (a file or a directory tree) into ``output``.

    Args:
        input_path: a frame file or a directory (walked recursively).
        output: the output directory (made if missing): the same names, dtypes, units, shapes and
            metadata as the inputs, with the depth cleaned; ``manifest.jsonl``, ``clean.toml``.
        config: the stages (default :class:`CleanConfig`: every piece measured, ``stage="auto"``).
        workers: DataLoader worker processes (local engine), 0: none.
        device: ``"auto"`` (GPU if any), ``"cpu"`` or ``"cuda[:N]"``.
        engine: ``"local"`` or ``"ray"`` (:mod:`.ray_engine`).
        progress: show a tqdm bar on stderr (None: when stderr is a terminal).
        concurrency: Ray actors running the pipeline (default 1 with a GPU each, else 2).
        ray_address: the Ray cluster (``ray.init(address=...)``); None: ``RAY_ADDRESS`` or a new
            local instance.
        compute_in_workers: local engine: compute in the workers (default: on the CPU only).
        figure: draw ``OUTPUT/report.png`` (:mod:`.figure`) when files were cleaned.

    Returns:
        a :class:`CleanReport` (``status`` is the exit status of ``tof-fpn clean``).

    Raises:
        ValueError: a bad argument or an OUTPUT that would overwrite INPUT (before anything is
            written). Bad input files do not raise: they are failed records in the manifest.
    """
    config = _checked(config, engine, workers)
    run = _Execution(engine, workers, resolve_device(device), progress, concurrency, ray_address,
                     compute_in_workers, figure)  # fmt: skip
    check_paths(input_path, output)
    jobs = plan_jobs(input_path, output)
    cameras = build_cameras(jobs, config)
    for c in cameras:
        c.pipeline.to(run.device)
    report = CleanReport(output, jobs=len(jobs), created=not os.path.isdir(output))
    report.stage = stage_lines(cameras, config.stage)
    report.stages_off = all(c.stages_off for c in cameras)
    os.makedirs(output, exist_ok=True)
    with output_lock(output):  # one run per OUTPUT at a time
        _saved_config(output, config)
        _run(output, config, jobs, cameras, report, run)
    return report


@dataclass(frozen=True)
class _Execution:
    """How a run executes (the arguments of :func:`clean` that do not change the output)."""

    engine: str
    workers: int
    device: torch.device
    progress: bool | None
    concurrency: int | None
    ray_address: str | None
    compute_in_workers: bool | None
    figure: bool


def _run(output, config, jobs, cameras: list[Camera], report: CleanReport, run: _Execution) -> None:
    """Steps 3-5 of the module docstring, OUTPUT locked and its configuration saved."""
    manifest_path = os.path.join(output, MANIFEST)
    done = finished(read_manifest(manifest_path), jobs)
    remove_stale_temporaries(output)
    report.already_done = len(done)
    groups = [
        (g, todo, i)
        for i, c in enumerate(cameras)
        for g in groups_of(c.jobs, config.batch)
        if (todo := {j.name for j in g} - done)
    ]
    camera_of = {j.name: c.key for c in cameras for j in c.jobs}
    token = f"{os.getpid()}-{secrets.token_hex(4)}"
    t0 = time.perf_counter()
    with Manifest(manifest_path) as man, _signals() as caught:
        todo = sum(len(t) for _, t, _ in groups)
        man.write(
            {
                "event": "start", "run": token, "version": __version__, "engine": run.engine,
                "workers": run.workers, "device": str(run.device), "jobs": len(jobs),
                "todo": todo, "already_done": len(done),
                **start_fields(cameras), "time": now(),
            }
        )  # fmt: skip
        for job in jobs:
            if job.error is not None:
                rec = {"file": job.name, "status": "failed", "error": job.error}
                man.write({**rec, "time": now()})
                report.add(rec)
        pipelines = [c.pipeline for c in cameras]
        stream = _engine_stream(
            run, groups, pipelines, config, token=token, root=output, stop=lambda: bool(caught)
        )
        _consume(stream, man, report, todo, run.progress, camera_of)
        _remove_own_temporaries(output, token)
        report.seconds = time.perf_counter() - t0
        report.interrupted = caught[0] if caught else None
        if run.figure and report.done and report.interrupted is None:
            report.figure = _figure(output, jobs, config, learned_patterns(cameras))
        man.write(
            {
                "event": "end", "run": token, "done": report.done, "failed": report.failed,
                "interrupted": report.interrupted, "seconds": round(report.seconds, 3),
                "time": now(),
            }
        )  # fmt: skip


def _checked(config, engine: str, workers) -> CleanConfig:
    """The configuration, after refusing bad arguments before anything is read or written."""
    config = CleanConfig() if config is None else config
    if not isinstance(config, CleanConfig):
        raise TypeError(
            f"config must be a CleanConfig or None, got {type(config).__name__} {config!r}: "
            "build one with CleanConfig(destripe='columns', ...) or read a TOML file with "
            "load_config(path)"
        )
    if engine not in ENGINES:
        raise ValueError(f"engine must be one of {list(ENGINES)}, got {engine!r}")
    if engine == "ray" and importlib.util.find_spec("ray") is None:
        raise ValueError(
            "--engine ray needs Ray Data: pip install 'tof_fpn_torch[ray]' (ray[data] >= 2.9)"
        )
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 0:
        raise ValueError(f"workers must be an int >= 0, got {workers!r}")
    return config


def _engine_stream(run: _Execution, groups, pipelines, config, **kw):
    """The records of the groups ``(jobs, todo, camera)``, from the local or the Ray engine."""
    if run.engine == "local":
        from .local import run_local

        return run_local(
            groups, pipelines, config, workers=run.workers, device=run.device,
            compute_in_workers=run.compute_in_workers, **kw,
        )  # fmt: skip
    from .ray_engine import run_ray

    return run_ray(
        groups, pipelines, config, device=run.device, concurrency=run.concurrency,
        address=run.ray_address, **kw,
    )  # fmt: skip


def _consume(stream, man: Manifest, report: CleanReport, total: int, progress, camera_of) -> None:
    """Append each record to the manifest as its file lands (with its ``camera``, the key of
    its camera group, from ``camera_of``), count it, show progress."""
    bar = tqdm(
        total=total,
        unit="file",
        desc="clean",
        disable=None if progress is None else not progress,
        file=sys.stderr,
    )
    try:
        for records in stream:
            for rec in records:
                rec["camera"] = camera_of.get(rec["file"])
                man.write(rec)
                report.add(rec)
            bar.update(len(records))
    finally:
        stream.close()
        bar.close()


def _figure(output: str, jobs, config: CleanConfig, patterns=None) -> str | None:
    """``OUTPUT/report.png`` (its path), or why it was not drawn: the files are cleaned anyway."""
    try:
        return report_figure(output, jobs, config, pattern_mm=patterns)
    except Exception as exc:  # noqa: BLE001
        return f"not drawn: {type(exc).__name__}: {exc}"


def _remove_own_temporaries(output: str, token: str) -> None:
    """This run's temporary files (a worker stopped mid-write leaves them)."""
    for folder, _, files in os.walk(output):
        for f in files:
            if f.startswith(".") and f"{TMP_MARK}{token}" in f:
                with contextlib.suppress(FileNotFoundError):
                    os.remove(os.path.join(folder, f))
