"""The Ray engine of ``tof-fpn clean`` (``--engine ray``): the same groups, steps and manifest as
the local engine, spread over a Ray cluster with Ray Data.

Dataflow (one row per group of files and its camera; ``batch_size=1`` row per call)::

    ray.data.from_items(groups)                  the file list, in fixed groups (plan.groups_of)
                                                 per camera (cameras.camera_groups)
      .map_batches(_load)                        tasks: read + decode (work.load_group)
      .map_batches(_Compute, ActorPoolStrategy(size=N))      actor pool: the torch pipelines (one
                                                 per camera), on a GPU each when the run's device
                                                 is CUDA (compute_group)
      .map_batches(_write)                       tasks: encode, temporary name, rename
      .iter_batches()                            the driver appends the records to the manifest

Every frame is computed alone (:mod:`.work`), so the bytes written depend on neither the groups nor
the engine: the files equal the local engine's byte for byte (tested). The driver keeps the resume
logic: it plans, reads the manifest and submits only groups with unfinished files. Workers write
the output files themselves, so on a real cluster OUTPUT (and INPUT) must be one shared file system
mounted at the same path on every node, and ``tof_fpn_torch`` importable there (docs/clean.md).
"""

from __future__ import annotations

import json
import logging
import os
import pickle
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import numpy as np
import torch

from .config import CleanConfig
from .plan import Job
from .work import compute_group, load_group, write_group

__all__ = ["run_ray", "start_ray"]


def _load(batch: dict, config: CleanConfig) -> dict:
    out = []
    for blob in batch["group"]:
        jobs, todo, camera = pickle.loads(blob)
        out.append(pickle.dumps((camera, load_group(jobs, todo, config))))
    return {"payload": np.array(out, dtype=object)}


class _Compute:
    """An actor holding the pipelines, one per camera (built once on the driver, shipped
    pickled); a group runs through its camera's."""

    def __init__(self, pipelines_blob: bytes, device: str) -> None:
        torch.set_num_threads(1)
        self.device = torch.device(device)
        self.pipelines = [p.to(self.device) for p in pickle.loads(pipelines_blob)]

    def __call__(self, batch: dict) -> dict:
        out = []
        for blob in batch["payload"]:
            camera, group = pickle.loads(blob)
            group = compute_group(self.pipelines[camera], group, self.device)
            out.append(pickle.dumps(group))
        return {"payload": np.array(out, dtype=object)}


def _write(batch: dict, token: str, root: str, config: CleanConfig) -> dict:
    records = [
        json.dumps(write_group(pickle.loads(blob), token, root, config))
        for blob in batch["payload"]
    ]
    return {"records": np.array(records, dtype=object)}


def start_ray(address: str | None = None):
    """Connect to ``address`` (or ``RAY_ADDRESS``), or start a local instance whose workers import
    this copy of the package; returns ``(ray, started)``. Raises ``ValueError`` saying what to
    install when Ray is missing."""
    try:
        import ray
    except ImportError:
        raise ValueError(
            "--engine ray needs Ray Data: pip install 'tof_fpn_torch[ray]' (ray[data] >= 2.9)"
        ) from None
    if ray.is_initialized():
        return ray, False
    address = address or os.environ.get("RAY_ADDRESS")
    if address:
        ray.init(address=address, log_to_driver=False)
    else:
        package_root = str(Path(__file__).resolve().parents[2])
        env = {
            "PYTHONPATH": os.pathsep.join(
                filter(None, [package_root, os.environ.get("PYTHONPATH")])
            )
        }
        ray.init(include_dashboard=False, log_to_driver=False, runtime_env={"env_vars": env})
    return ray, True


def run_ray(
    groups: list[tuple[list[Job], set[str], int]],
    pipelines: Sequence[torch.nn.Module],
    config: CleanConfig,
    *,
    token: str,
    root: str,
    stop: Callable[[], bool],
    device: torch.device | str = "cpu",
    concurrency: int | None = None,
    address: str | None = None,
) -> Iterator[list[dict]]:
    """Yield the manifest records of each group as its files land (any order), each group
    computed with ``pipelines[camera]``; after ``stop()`` is true, take no more results (the tasks in flight finish or are dropped with Ray)."""
    ray, started = start_ray(address)
    device = torch.device(device)
    gpu = device.type == "cuda"
    if concurrency is None:
        cpus = int(ray.available_resources().get("CPU", 2))
        concurrency = 1 if gpu else max(1, cpus // 2)
    if isinstance(concurrency, bool) or not isinstance(concurrency, int) or concurrency < 1:
        raise ValueError(f"concurrency must be an int >= 1, got {concurrency!r}")
    ctx = ray.data.DataContext.get_current()
    ctx.enable_progress_bars = False
    logging.getLogger("ray.data").setLevel(logging.WARNING)
    try:
        if not groups:
            return
        items = [{"group": pickle.dumps(g)} for g in groups]
        ds = ray.data.from_items(items, override_num_blocks=len(items))
        ds = ds.map_batches(_load, batch_size=1, fn_kwargs={"config": config})
        blob = pickle.dumps([p.cpu() for p in pipelines])
        dev = "cuda" if gpu else "cpu"

        class _Bound(_Compute):  # the module travels with the class, not as an object-store arg
            def __init__(self) -> None:
                super().__init__(blob, dev)

        ds = ds.map_batches(
            _Bound,
            batch_size=1,
            compute=ray.data.ActorPoolStrategy(size=concurrency),
            num_gpus=1 if gpu else 0,
        )
        ds = ds.map_batches(
            _write, batch_size=1, fn_kwargs={"token": token, "root": root, "config": config}
        )
        for rows in ds.iter_batches(batch_size=1, batch_format="numpy"):
            yield [rec for text in rows["records"] for rec in json.loads(text)]
            if stop():
                return
    finally:
        if started:
            ray.shutdown()
