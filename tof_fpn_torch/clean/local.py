"""The local engine of ``tof-fpn clean``: one machine, a ``torch.utils.data.DataLoader`` for
parallel reading (and, on the CPU, computing and writing).

* ``workers = 0``: every step in this process, group after group.
* ``workers = N`` on the CPU: ``N`` DataLoader worker processes each load, compute (one torch
  thread each) and write whole groups; this process only records the results.
* ``workers = N`` on a GPU: the workers load (decode); this process computes on the GPU, frame
  after frame, and ``N`` threads encode and write.

Each group of files is ``(jobs, todo, camera)``: ``camera`` indexes the pipeline its files run
through (one per camera group, :mod:`.cameras`).

Workers ignore SIGINT / SIGTERM (this process decides when to stop: it finishes the groups in
flight, see :func:`tof_fpn_torch.clean.clean`) and are killed by the kernel when this process dies
(``PR_SET_PDEATHSIG`` on Linux), so a killed run leaves no worker writing behind it.
"""

from __future__ import annotations

import contextlib
import signal
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor

import torch
from torch.utils.data import DataLoader, Dataset

from .config import CleanConfig
from .plan import Job
from .work import compute_group, load_group, write_group

__all__ = ["run_local"]


def _identity(x):
    return x


def _worker_init(_: int) -> None:
    torch.set_num_threads(1)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    with contextlib.suppress(OSError, AttributeError):
        import ctypes

        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG: die with the main process


class _Groups(Dataset):
    """Item ``i``: group ``i`` loaded, with its camera (``pipelines`` None), or loaded, computed
    with its camera's pipeline and written (its manifest records)."""

    def __init__(self, groups, config, pipelines, token: str, root: str) -> None:
        self.groups, self.config, self.pipelines = groups, config, pipelines
        self.token, self.root = token, root

    def __len__(self) -> int:
        return len(self.groups)

    def __getitem__(self, i: int):
        jobs, todo, camera = self.groups[i]
        group = load_group(jobs, todo, self.config)
        if self.pipelines is None:
            return camera, group
        compute_group(self.pipelines[camera], group, "cpu")
        return write_group(group, self.token, self.root, self.config)


def run_local(
    groups: list[tuple[list[Job], set[str], int]],
    pipelines: Sequence[torch.nn.Module],
    config: CleanConfig,
    *,
    token: str,
    root: str,
    stop: Callable[[], bool],
    workers: int = 0,
    device: torch.device | str = "cpu",
    compute_in_workers: bool | None = None,
) -> Iterator[list[dict]]:
    """Yield the manifest records of each group, in group order, each group computed with
    ``pipelines[camera]``; stop after the groups in flight once ``stop()`` is true."""
    if workers == 0:
        for jobs, todo, camera in groups:
            if stop():
                return
            group = load_group(jobs, todo, config)
            compute_group(pipelines[camera], group, device)
            yield write_group(group, token, root, config)
        return
    device = torch.device(device)
    in_workers = device.type == "cpu" if compute_in_workers is None else compute_in_workers
    cpu = [p.cpu() for p in pipelines] if in_workers else None
    data = _Groups(groups, config, cpu, token, root)
    loader = DataLoader(
        data,
        batch_size=None,
        shuffle=False,
        num_workers=workers,
        collate_fn=_identity,
        worker_init_fn=_worker_init,
    )
    it = iter(loader)
    try:
        if in_workers:
            for records in it:
                yield records
                if stop():
                    return
            return
        with ThreadPoolExecutor(workers) as pool:
            pending: deque = deque()
            for camera, group in it:
                compute_group(pipelines[camera], group, device)
                pending.append(pool.submit(write_group, group, token, root, config))
                while pending and (pending[0].done() or len(pending) > 2 * workers):
                    yield pending.popleft().result()
                if stop():
                    break
            while pending:
                yield pending.popleft().result()
    finally:
        shutdown = getattr(it, "_shutdown_workers", None)
        if shutdown is not None:
            shutdown()  # the workers finish the group they are on, then exit
